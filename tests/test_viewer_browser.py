"""`mhrc show`'s report in a real headless browser (Debian's chromium and chromedriver, driven
by selenium): the map, the lanes and the slider render, and scrubbing moves the robots."""

from __future__ import annotations

import asyncio
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from test_viewer import record_failed, record_heuristic

from mhrc.cli import main
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process

pytestmark = pytest.mark.slow

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
INSTALL = "scripts/install-browser.sh"  # .ci/run runs it before pytest


@pytest.fixture(scope="session")
def browser() -> tuple[Path, Path]:
    """Debian's chromium and chromedriver, installed by scripts/install-browser.sh (a test never
    installs anything). Without them the test is skipped, saying how to get them; in CI
    (CI=true) it fails instead, so that CI never passes by skipping."""
    missing = [str(path) for path in (CHROMIUM, CHROMEDRIVER) if not path.is_file()]
    if missing:
        why = f"no headless browser: {', '.join(missing)} missing; run {INSTALL} (as root or with sudo) to install it"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{why} (CI=true: the browser tests must run in CI)", pytrace=False)
        pytest.skip(why)
    return CHROMIUM, CHROMEDRIVER


def chrome(browser: tuple[Path, Path], size: str = "1400,1800") -> Any:
    """A headless chromium session (selenium) of the `browser` fixture's binaries."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chromium, chromedriver = browser
    options = webdriver.ChromeOptions()
    options.binary_location = str(chromium)
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu", f"--window-size={size}"):
        options.add_argument(arg)
    return webdriver.Chrome(service=Service(str(chromedriver)), options=options)


@pytest.fixture
def driver(browser: tuple[Path, Path]) -> Iterator[Any]:
    drv = chrome(browser)
    try:
        yield drv
    finally:
        drv.quit()


def _show(trace: Path) -> Path:
    result = CliRunner().invoke(main, ["show", str(trace)])
    assert result.exit_code == 0, result.output
    return Path(result.output.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _show(record_heuristic(tmp_path_factory.mktemp("browser") / "trace.jsonl"))


@pytest.fixture(scope="module")
def failed_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _show(record_failed(tmp_path_factory.mktemp("browser-failed") / "trace.jsonl"))


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

    # the slider, at the end: the state the episode was judged on, no step greyed as still to come
    slider = driver.find_element(By.ID, "tick-slider")
    label = driver.find_element(By.ID, "tick-label")
    last = len(frames) - 1
    assert slider.is_displayed() and int(slider.get_attribute("max")) == last
    assert (
        label.get_attribute("data-frame") == str(last)
        and int(driver.execute_script("return arguments[0].value", slider)) == last
    )
    assert _robots(driver) == {r: (p["x"], p["y"]) for r, p in frames[last]["robots"].items()}
    assert not driver.find_elements(By.CSS_SELECTOR, ".step.future")
    steps = driver.find_elements(By.CSS_SELECTOR, ".lane li.step")
    assert all(float(el.value_of_css_property("opacity")) == 1.0 for el in steps)

    # Home: the start; every executed step is then still to come
    body = driver.find_element(By.TAG_NAME, "body")
    body.send_keys(Keys.HOME)
    assert label.get_attribute("data-frame") == "0"
    start = _robots(driver)
    assert start == {r: (p["x"], p["y"]) for r, p in frames[0]["robots"].items()}
    future = driver.find_elements(By.CSS_SELECTOR, ".step.future")
    assert len(future) == len(driver.find_elements(By.CSS_SELECTOR, ".step[data-frame]")) > 0
    assert all(float(el.value_of_css_property("opacity")) < 1.0 for el in future)

    # the right arrow key, with the focus on the page: one frame on
    body.send_keys(Keys.ARROW_RIGHT)
    assert label.get_attribute("data-frame") == "1"
    assert label.get_attribute("data-tick") == str(frames[1]["tick"])
    assert _robots(driver) == {r: (p["x"], p["y"]) for r, p in frames[1]["robots"].items()}
    assert driver.find_elements(By.CSS_SELECTOR, ".step.current")

    # the slider itself: to a frame where the robots have moved since the start
    moved = next(
        i for i, f in enumerate(frames) if i > 1 and any((p["x"], p["y"]) != start[r] for r, p in f["robots"].items())
    )
    driver.execute_script(
        "const s = arguments[0]; s.value = arguments[1]; s.dispatchEvent(new Event('input', {bubbles: true}));",
        slider,
        moved,
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


def _boxes(drv: Any, selector: str) -> list[dict[str, Any]]:
    """The rendered boxes (getBBox, SVG user units) of the map's elements matching `selector`."""
    return drv.execute_script(
        "return Array.from(document.querySelectorAll(arguments[0])).filter(e => e.textContent !== '' || e.tagName !== 'text')"
        ".map(e => "
        "{ const b = e.getBBox(); return {text: e.textContent, cls: e.getAttribute('class'), stack: e.getAttribute('data-stack'), "
        "x0: b.x, y0: b.y, x1: b.x + b.width, y1: b.y + b.height}; });",
        selector,
    )


def _overlap(a: dict[str, Any], b: dict[str, Any]) -> float:
    w = min(a["x1"], b["x1"]) - max(a["x0"], b["x0"])
    h = min(a["y1"], b["y1"]) - max(a["y0"], b["y0"])
    return w * h if w > 0 and h > 0 else 0.0


def test_a_failed_episode_shows_its_unplaced_targets_in_a_browser(driver: Any, failed_report: Path) -> None:
    """The report of an episode cut off with targets unplaced: the Targets section lists them
    with where they ended, the map marks them at the end, and no label covers another."""
    from selenium.webdriver.common.by import By

    driver.get(failed_report.as_uri())
    assert not [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
    data = json.loads(driver.find_element(By.ID, "mhrc-data").get_attribute("textContent"))
    frames, last = data["frames"], len(data["frames"]) - 1
    end = frames[last]["objects"]
    targets = [n for n, r in data["roles"].items() if r == "target"]
    unplaced = [t for t in targets if end[t]["on"] != data["goals"][t] or end[t]["held_by"]]
    assert targets and unplaced and len(unplaced) < len(targets)

    # the Targets section, above the map, visible, naming each unplaced target and where it is
    section = driver.find_element(By.ID, "targets")
    assert section.is_displayed() and section.location["y"] < driver.find_element(By.ID, "map").location["y"]
    summary = section.find_element(By.CSS_SELECTOR, ".tsum").text
    assert f"{len(unplaced)} of {len(targets)} targets not placed" in summary
    rows = {r.get_attribute("data-name"): r for r in section.find_elements(By.CSS_SELECTOR, "tr[data-role]")}
    assert [n for n, r in rows.items() if r.get_attribute("data-role") == "target"] == targets
    for t in unplaced:
        row = rows[t]
        assert row.is_displayed() and row.get_attribute("data-placed") == "no"
        assert "not placed" in row.text and t in summary
        tint = row.find_element(By.CSS_SELECTOR, "td").value_of_css_property("background-color")
        assert tint.startswith("rgb") and tint not in ("rgba(0, 0, 0, 0)", "rgb(255, 255, 255)"), (
            tint
        )  # the row stands out
        where = (
            f"held by {end[t]['held_by']}"
            if end[t]["held_by"]
            else f"{'in' if end[t]['inside'] else 'on'} {end[t]['on']}"
        )
        assert where in row.text and where in summary
    for n, row in rows.items():
        if row.get_attribute("data-role") == "distractor":
            assert "distractor" in row.text and n in summary

    # the map at the end: each object styled by its role; the unplaced targets ringed
    drawn = {g.get_attribute("data-name"): g for g in driver.find_elements(By.CSS_SELECTOR, "#map g.object")}
    assert set(drawn) == set(end)
    for name, g in drawn.items():
        role = g.get_attribute("data-role")
        assert role == ("target unplaced" if name in unplaced else "target placed" if name in targets else "distractor")
        assert bool(g.find_elements(By.CSS_SELECTOR, "circle.ring")) == (name in unplaced)
    fills = {
        g.get_attribute("data-role"): g.find_element(By.CSS_SELECTOR, "circle.obj").value_of_css_property("fill")
        for g in drawn.values()
    }
    assert len(set(fills.values())) == len(fills) == 3  # three roles, three colours

    # the paths follow the planned routes: every route's waypoints are on its robot's path
    paths = {p.get_attribute("data-robot"): p for p in driver.find_elements(By.CSS_SELECTOR, "#map polyline.path")}
    svg = driver.find_element(By.ID, "map")
    xmin, ymax, scale = (float(svg.get_attribute(f"data-{k}")) for k in ("xmin", "ymax", "scale"))
    routed = 0
    for goal, route in data["routes"].items():
        robot = data["calls"][goal]["robot"]
        points = [tuple(map(float, p.split(","))) for p in paths[robot].get_attribute("points").split()]
        for x, y in route:
            assert any(
                abs(px - (x - xmin) * scale) < 0.2 and abs(py - (ymax - y) * scale) < 0.2 for px, py in points
            ), (goal, x, y)
        routed += 1
    assert routed and sum(int(p.get_attribute("data-routes")) for p in paths.values()) == routed

    # no label covers another, nor a robot's or an object's dot, at any frame
    for i in [last, *range(last)]:
        driver.execute_script(
            "const s = arguments[0]; s.value = arguments[1]; s.dispatchEvent(new Event('input', {bubbles: true}));",
            driver.find_element(By.ID, "tick-slider"),
            i,
        )
        labels = _boxes(driver, "#map text")
        named = sum(
            len(a["stack"].split(",")) if a["stack"] else 1 for a in labels
        )  # a stack's label lists its objects
        assert named >= len(frames[i]["objects"]) + len(frames[i]["robots"]) + 1
        for k, a in enumerate(labels):
            for b in labels[k + 1 :]:
                assert _overlap(a, b) < 0.5, (i, a, b)
        dots = _boxes(driver, "#map g.robot circle, #map g.object circle.obj")
        for a in _boxes(driver, "#labels text"):
            for d in dots:
                assert _overlap(a, d) < 1.0, (i, a, d)


def test_a_drone_is_drawn_flying_at_its_altitude(driver: Any, tmp_path: Path) -> None:
    """A team with a drone: the map draws it with its rotors (a dashed ring), its altitude in
    the house it flew in on its label and on hover; the ground robots are drawn as ever."""
    from selenium.webdriver.common.by import By

    from mhrc.world.kinds import KINDS, flight_altitude
    from mhrc.world.scene import get_layout
    from mhrc.world.teams import SHIPPED

    trace = tmp_path / "trace.jsonl"
    asyncio.run(
        up_in_process(EpisodeConfig.build(team=SHIPPED["drone_scout"], seed=0, horizon=6, trace=trace).resolved())
    )
    driver.get(_show(trace).as_uri())
    want = flight_altitude(KINDS["drone"], max(f.size[2] for f in get_layout("kitchen").furniture))
    (drone,) = driver.find_elements(By.CSS_SELECTOR, "#map g.robot.flying")
    assert drone.get_attribute("data-robot") == "lucy" and float(drone.get_attribute("data-altitude")) == want
    assert drone.find_elements(By.CSS_SELECTOR, "circle.rotors")
    labels = [t.text for t in driver.find_elements(By.CSS_SELECTOR, "#map text") if t.text.startswith("lucy")]
    assert labels == [f"lucy ({want:.1f} m up)"], labels
    assert {g.get_attribute("data-robot") for g in driver.find_elements(By.CSS_SELECTOR, "#map g.robot")} == {
        "alice",
        "bob",
        "lucy",
    }
