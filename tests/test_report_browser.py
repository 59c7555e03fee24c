"""The report (`mhrc show`) in real chromium for what a large or oddly named team brings (issue 42
item 5, issue 43 items 9 and 15): a robot named like a JavaScript object's member is drawn; an
8-robot team's lanes fit the page at 1400 px, scroll together in one box and put each tick at the
same height in every lane; a stack's objects are listed in one label, not printed over each other."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_viewer_browser import _boxes, _overlap, _robots, _show, browser, chrome

from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.run.teams import resolve_team

pytestmark = pytest.mark.slow
__all__ = ["browser"]  # the fixture, imported for the tests below


@pytest.fixture
def wide(browser: tuple[Path, Path]) -> Iterator[Any]:
    drv = chrome(browser, "1400,1000")
    try:
        yield drv
    finally:
        drv.quit()


def _record(path: Path, **options: Any) -> Path:
    asyncio.run(up_in_process(EpisodeConfig.build(trace=path, **options).resolved()))
    return path


def _no_errors(drv: Any) -> None:
    assert not [e for e in drv.get_log("browser") if e.get("level") == "SEVERE"]


def _slide(drv: Any, frame: int) -> None:
    from selenium.webdriver.common.by import By

    drv.execute_script(
        "const s = arguments[0]; s.value = arguments[1]; s.dispatchEvent(new Event('input', {bubbles: true}));",
        drv.find_element(By.ID, "tick-slider"),
        frame,
    )


def test_a_robot_named_constructor_is_drawn(wide: Any, tmp_path: Path) -> None:
    """page.js read data.fliers['constructor'] (JavaScript's Object) and drew no robot at all."""
    team = resolve_team("constructor=mobile_manipulator,bob=tabletop_arm,david=mobile_base")
    report = _show(_record(tmp_path / "trace.jsonl", team=team, seed=0, horizon=3))
    wide.get(report.as_uri())
    _no_errors(wide)
    assert set(_robots(wide)) == {"constructor", "bob", "david"}
    assert not wide.find_elements("css selector", "#map g.robot.flying")  # no robot taken for a drone
    lanes = [lane.get_attribute("data-robot") for lane in wide.find_elements("css selector", ".lane")]
    assert lanes == ["constructor", "bob", "david"]


@pytest.fixture(scope="module")
def full_house(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from mhrc.world.teams import SHIPPED

    trace = tmp_path_factory.mktemp("full_house") / "trace.jsonl"
    return _show(_record(trace, team=SHIPPED["full_house"], seed=0, horizon=10))


def _lane_boxes(drv: Any) -> dict[str, Any]:
    return drv.execute_script(
        """const box = document.getElementById('lanes'), r = e => { const b = e.getBoundingClientRect();
             return {left: b.left, right: b.right, top: b.top, bottom: b.bottom}; };
           return {page: {client: document.documentElement.clientWidth, scroll: document.documentElement.scrollWidth},
             box: Object.assign(r(box), {scrollTop: box.scrollTop, scrollWidth: box.scrollWidth, clientWidth: box.clientWidth,
                                         scrollHeight: box.scrollHeight, clientHeight: box.clientHeight}),
             lanes: Array.from(box.querySelectorAll('.lane')).map(l => Object.assign(r(l), {robot: l.dataset.robot})),
             cells: Array.from(box.querySelectorAll('.tick-cell')).map(c => Object.assign(r(c),
                 {robot: c.closest('.lane').dataset.robot, tick: c.dataset.tick})),
             current: Array.from(box.querySelectorAll('.step.current')).map(r)};"""
    )


def test_an_eight_robot_report_fits_1400_px_and_its_ticks_line_up(wide: Any, full_house: Path) -> None:
    """The lanes of full_house ran off the page, each scrolling on its own, a tick at a different
    height in each lane."""
    wide.get(full_house.as_uri())
    _no_errors(wide)
    data = json.loads(wide.find_element("id", "mhrc-data").get_attribute("textContent"))
    assert len(data["robots"]) == 8
    got = _lane_boxes(wide)
    assert got["page"]["scroll"] <= got["page"]["client"], got["page"]  # the page itself never scrolls across
    box = got["box"]
    assert box["right"] <= got["page"]["client"] and box["scrollWidth"] <= box["clientWidth"] + 1, box
    assert [lane["robot"] for lane in got["lanes"]] == data["robots"]
    for lane in got["lanes"]:  # every lane whole, side by side, inside the box
        assert box["left"] - 1 <= lane["left"] and lane["right"] <= box["right"] + 1, (lane, box)
    assert all(a["right"] <= b["left"] for a, b in zip(got["lanes"], got["lanes"][1:], strict=False))
    by_tick: dict[str, list[dict[str, Any]]] = {}
    for cell in got["cells"]:
        by_tick.setdefault(cell["tick"], []).append(cell)
    assert len(by_tick) >= 10
    for tick, cells in by_tick.items():
        assert len({c["robot"] for c in cells}) == len(cells) == 8, tick  # each robot acted once a tick here
        assert max(c["top"] for c in cells) - min(c["top"] for c in cells) < 1, (tick, cells)
    tops = sorted((float(t), min(c["top"] for c in cs)) for t, cs in by_tick.items())
    assert all(a[1] < b[1] for a, b in zip(tops, tops[1:], strict=False))  # later ticks below

    # the lanes follow the slider in their own box: the current steps in view, the page unmoved
    page_y = wide.execute_script("return window.scrollY")
    for frame in (0, len(data["frames"]) - 1):
        _slide(wide, frame)
        got = _lane_boxes(wide)
        assert wide.execute_script("return window.scrollY") == page_y
        if frame == 0:
            assert got["box"]["scrollTop"] == 0
        for step in got["current"]:
            assert got["box"]["top"] <= step["top"] < got["box"]["bottom"], (frame, step, got["box"])


def test_a_stacks_objects_are_listed_in_one_label(wide: Any, tmp_path: Path) -> None:
    """The stacked sandwich's four labels were crowded round one point, over one another and the
    robot's; now one label lists the stack, top first, and no two labels overlap."""
    report = _show(_record(tmp_path / "trace.jsonl", task="make_sandwich", seed=0, horizon=30))
    wide.get(report.as_uri())
    _no_errors(wide)
    data = json.loads(wide.find_element("id", "mhrc-data").get_attribute("textContent"))
    end = data["frames"][-1]["objects"]
    on_board = sorted((n for n, o in end.items() if o["on"] == data["goals"].get(n)), key=lambda n: -end[n]["z"])
    assert len(on_board) >= 3, end  # the test needs a stack
    labels = _boxes(wide, "#labels text")
    stacks = [a for a in labels if a["stack"]]
    assert [a["stack"].split(",") for a in stacks] == [on_board], (stacks, on_board)
    every = _boxes(wide, "#map text")
    for k, a in enumerate(every):
        for b in every[k + 1 :]:
            assert _overlap(a, b) < 0.5, (a, b)
