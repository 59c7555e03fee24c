"""`mhrc show`'s report in a real headless browser (Debian's chromium and chromedriver, driven
by selenium): the map, the lanes and the slider render, and scrubbing moves the robots."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from mhrc.cli import main
from test_viewer import record_heuristic

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")


@pytest.fixture(scope="session")
def browser_installed() -> None:
    """Runs scripts/install-browser.sh (a no-op when both are there); fails, saying why, if it cannot."""
    script = ROOT / "scripts" / "install-browser.sh"
    proc = subprocess.run(["sh", str(script)], capture_output=True, text=True, timeout=900)
    if proc.returncode != 0 or not (CHROMIUM.exists() and CHROMEDRIVER.exists()):
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        pytest.fail(
            f"could not install the headless browser with {script} (exit {proc.returncode}): {' | '.join(tail)}. "
            "Run it as root (or with sudo), or install Debian's chromium and chromium-driver packages.",
            pytrace=False,
        )


@pytest.fixture
def driver(browser_installed: None) -> Iterator[Any]:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu", "--window-size=1400,1800"):
        options.add_argument(arg)
    drv = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
    try:
        yield drv
    finally:
        drv.quit()


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    trace = record_heuristic(tmp_path_factory.mktemp("browser") / "trace.jsonl")
    result = CliRunner().invoke(main, ["show", str(trace)])
    assert result.exit_code == 0, result.output
    return Path(result.output.strip().splitlines()[-1])


def _robots(drv: Any) -> dict[str, tuple[float, float]]:
    from selenium.webdriver.common.by import By

    return {
        g.get_attribute("data-robot"): (float(g.get_attribute("data-x")), float(g.get_attribute("data-y")))
        for g in drv.find_elements(By.CSS_SELECTOR, "#map g.robot")
    }


def test_the_report_renders_and_scrubs_in_a_browser(driver: Any, report: Path, tmp_path: Path) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    driver.get(report.as_uri())
    errors = [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
    assert not errors, errors

    data = json.loads(driver.find_element(By.ID, "mhrc-data").get_attribute("textContent"))
    frames = data["frames"]
    assert len(frames) > 2

    # the map: furniture from the scene, every robot drawn, objects drawn
    svg = driver.find_element(By.ID, "map")
    assert svg.is_displayed() and svg.size["width"] > 300
    names = {el.get_attribute("data-name") for el in driver.find_elements(By.CSS_SELECTOR, "#map rect.furniture")}
    assert {"table_0", "fridge", "sofa"} <= names
    assert driver.find_elements(By.CSS_SELECTOR, "#map rect.goal-area")
    assert set(_robots(driver)) == set(data["robots"])
    assert len(driver.find_elements(By.CSS_SELECTOR, "#map g.object")) == len(frames[0]["objects"])

    # the lanes: one per robot, every step drawn
    lanes = driver.find_elements(By.CSS_SELECTOR, ".lane")
    assert [lane.get_attribute("data-robot") for lane in lanes] == data["robots"]
    assert all(lane.is_displayed() for lane in lanes)
    assert len(driver.find_elements(By.CSS_SELECTOR, ".lane li.step")) == len(data["calls"])

    # the slider
    slider = driver.find_element(By.ID, "tick-slider")
    label = driver.find_element(By.ID, "tick-label")
    assert slider.is_displayed() and int(slider.get_attribute("max")) == len(frames) - 1
    assert label.get_attribute("data-frame") == "0"
    start = _robots(driver)
    assert start == {r: (p["x"], p["y"]) for r, p in frames[0]["robots"].items()}

    # the right arrow key, with the focus on the page: one frame on
    driver.find_element(By.TAG_NAME, "body").send_keys(Keys.ARROW_RIGHT)
    assert label.get_attribute("data-frame") == "1"
    assert label.get_attribute("data-tick") == str(frames[1]["tick"])
    assert _robots(driver) == {r: (p["x"], p["y"]) for r, p in frames[1]["robots"].items()}
    assert driver.find_elements(By.CSS_SELECTOR, ".step.current")

    # the slider itself: to a frame where the robots have moved since the start
    moved = next(i for i, f in enumerate(frames) if i > 1 and any((p["x"], p["y"]) != start[r] for r, p in f["robots"].items()))
    driver.execute_script(
        "const s = arguments[0]; s.value = arguments[1]; s.dispatchEvent(new Event('input', {bubbles: true}));", slider, moved
    )
    assert label.get_attribute("data-frame") == str(moved)
    assert f"tick {frames[moved]['tick']}" in label.text
    now = _robots(driver)
    assert now != start and now == {r: (p["x"], p["y"]) for r, p in frames[moved]["robots"].items()}
    paths = driver.find_elements(By.CSS_SELECTOR, "#map polyline.path")
    assert paths  # the robots' paths so far

    # the arrow keys on the focused slider move it too (the browser's own handling)
    slider.send_keys(Keys.ARROW_RIGHT)
    assert label.get_attribute("data-frame") == str(min(moved + 1, len(frames) - 1))

    shot = tmp_path / "report.png"
    assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 10_000
