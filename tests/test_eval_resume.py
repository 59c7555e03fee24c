"""`mhrc eval` interrupted and resumed exactly as it advises (issue 43): one "interrupted" line, no
bar off a terminal, and a printed command that finishes the interrupted grid (not the default
one) without running any episode twice; then the evaluation page, opened in a real headless
chromium, links every row to the report of that very episode."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from test_viewer_browser import browser as browser  # the session's chromium (a fixture)
from test_viewer_browser import chrome
from waits import interrupt_after_first_row

pytestmark = pytest.mark.slow

# a grid that is not the default one: 4 cheap heuristic episodes, a short horizon; scenes given kitchen first, so
# episodes finish (one worker) in an order that is not the page's, which lists them by key
GRID = ["--tasks", "pack_objects", "--scenes", "kitchen,bedroom", "--objects", "3,4", "--horizon", "12"]
KEYS = {f"pack_objects/{scene}/{n}/0" for scene in ("kitchen", "bedroom") for n in (3, 4)}
BAR = "━"  # rich's progress bar


@dataclass
class Interrupted:
    home: Path
    stderr: str  # the interrupted run's
    code: int
    before: str  # episodes.jsonl when the interrupt came, and when the run had ended
    after_stop: str
    advice: str
    resumed: subprocess.CompletedProcess[str]


def _rows(text: str) -> list[dict[str, Any]]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Interrupted]:
    home = tmp_path_factory.mktemp("interrupted")
    rows = home / "ev" / "episodes.jsonl"
    args = [sys.executable, "-m", "mhrc", "eval", *GRID, "--workers", "1", "--out", "ev"]
    returncode, before, text = interrupt_after_first_row(args, home, rows, 240)
    last = text.strip().splitlines()[-1]
    assert "finish the grid with: " in last, text[-2000:]
    advice = last.split("finish the grid with: ", 1)[1]
    after_stop = rows.read_text()
    words = shlex.split(advice)
    assert words[0] == "mhrc", advice
    resumed = subprocess.run(
        [sys.executable, "-m", "mhrc", *words[1:]], cwd=home, capture_output=True, text=True, timeout=300
    )
    yield Interrupted(home, text, returncode, before, after_stop, advice, resumed)


def test_an_interrupt_says_so_once_draws_no_bar_off_a_terminal_and_advises_a_command(
    interrupted: Interrupted,
) -> None:
    text = interrupted.stderr
    assert interrupted.code == 130, text[-2000:]
    assert text.count("interrupted") == 1 and "interrupted: stopping the workers" in text, text
    assert BAR not in text, text  # off a terminal: one line per episode, never a bar
    finished = [line for line in text.splitlines() if line.split(":")[0] in KEYS]
    assert finished and all("/4)" in line for line in finished), text  # "KEY: solved, TS n (i/4)"
    assert interrupted.advice == "mhrc eval --resume --out ev", interrupted.advice


def test_the_advice_run_as_printed_finishes_that_grid_and_nothing_more(interrupted: Interrupted) -> None:
    res = interrupted.resumed
    assert res.returncode == 0, res.stderr[-2000:]
    assert BAR not in res.stderr
    done_before = {r["key"] for r in _rows(interrupted.after_stop)}
    assert done_before and done_before < KEYS, done_before  # the interrupt left part of the grid
    rows = (interrupted.home / "ev" / "episodes.jsonl").read_text()
    assert rows.startswith(interrupted.before)  # the rows from before stand as they were
    keys = [r["key"] for r in _rows(rows)]
    assert sorted(keys) == sorted(KEYS), keys  # every episode of that grid once: none twice, none of another grid
    assert all(r["horizon"] == 12 for r in _rows(rows))
    ran_now = [line.split(":")[0] for line in res.stderr.splitlines() if line.split(":")[0] in KEYS]
    assert sorted(ran_now) == sorted(KEYS - done_before), res.stderr[-2000:]  # nothing re-run
    assert f"({len(done_before)} from before)]" in res.stderr  # said once, at the start
    assert f"({len(done_before) + 1}/4)" in res.stderr  # each line counts the whole grid


def test_resume_refuses_another_grid_rather_than_merge_it(interrupted: Interrupted) -> None:
    rows = (interrupted.home / "ev" / "episodes.jsonl").read_bytes()
    for extra, said in (
        (["--tasks", "sort_solids"], "--tasks was pack_objects, now sort_solids"),
        (["--scenes", "kitchen"], "--scenes was kitchen,bedroom, now kitchen"),
        (["--objects", "3,4,5"], "--objects was 3,4, now 3,4,5"),
        (["--horizon", "50"], "--horizon was 12, now 50"),
    ):
        res = subprocess.run(
            [sys.executable, "-m", "mhrc", "eval", "--resume", "--out", "ev", *extra],
            cwd=interrupted.home,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert res.returncode == 2 and said in res.stderr and "Traceback" not in res.stderr, res.stderr
    assert (interrupted.home / "ev" / "episodes.jsonl").read_bytes() == rows


def test_each_row_of_the_page_opens_the_report_of_its_own_episode(
    interrupted: Interrupted, browser: tuple[Path, Path]
) -> None:
    """Rows finished kitchen first; the page lists bedroom first. Each link must open its row's episode."""
    from selenium.webdriver.common.by import By

    assert interrupted.resumed.returncode == 0
    page = (interrupted.home / "ev" / "summary.html").resolve()
    drv = chrome(browser)
    try:
        drv.get(page.as_uri())
        links = []
        for tr in drv.find_elements(By.CSS_SELECTOR, "table tr"):
            cells = tr.find_elements(By.TAG_NAME, "td")
            if cells and cells[0].text in KEYS:
                (a,) = cells[-1].find_elements(By.TAG_NAME, "a")
                links.append((cells[0].text, a.get_attribute("href")))
        assert sorted(k for k, _ in links) == sorted(KEYS), links
        assert [k for k, _ in links] == sorted(KEYS)  # the page lists them by key, not as they finished
        for key, href in links:
            assert href.startswith(page.parent.as_uri() + "/traces/"), href
            drv.get(href)
            facts = {
                tr.find_element(By.TAG_NAME, "th").text: tr.find_element(By.TAG_NAME, "td").text
                for tr in drv.find_elements(By.CSS_SELECTOR, "table.facts tr")
            }
            task, scene, n, seed = key.split("/")
            assert (facts["task"], facts["scene"], facts["objects"], facts["seed"]) == (task, scene, n, seed), (
                key,
                href,
                facts,
            )
    finally:
        drv.quit()
