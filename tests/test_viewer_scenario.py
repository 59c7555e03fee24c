"""The report and the video of a dynamic episode show its scenario events (issue 25): the view
model, the HTML (timeline, lanes, header), a real headless chromium scrubbing to an event, and the
video's caption. Traces are recorded by the heuristic team with a real scenario (in process: real
Zenoh on loopback, real PyBullet)."""

from __future__ import annotations

import asyncio
import json
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import test_viewer_browser
from test_viewer import record_heuristic, show

from mhrc.core.protocol import ScenarioEvent, Snapshot
from mhrc.core.records import messages, read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.viewer.load import load_trace
from mhrc.viewer.model import build_view
from mhrc.viewer.video import read_episode
from mhrc.world.scenario import load_scenario
from mhrc.world.sim import Sim

browser, driver = test_viewer_browser.browser, test_viewer_browser.driver  # the browser tests' fixtures, shared

BUSY_HOUSE = Path(__file__).resolve().parents[1] / "world" / "scenarios" / "busy_house.json"
HORIZON = 20  # past busy_house's last event (tick 14) and its breakdown's end (tick 17)
SKIP_HORIZON = 3


def _record(path: Path, events: Path, horizon: int) -> Path:
    asyncio.run(up_in_process(EpisodeConfig.build(seed=0, horizon=horizon, trace=path, events=events).resolved()))
    return path


def _events(trace: Path) -> list[ScenarioEvent]:
    return messages(read_records(trace), ScenarioEvent)


@pytest.fixture(scope="module")
def busy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """seed 0 with the shipped busy_house scenario: relocate, close, breakdown, new_target, all applied."""
    trace = _record(tmp_path_factory.mktemp("busy") / "trace.jsonl", BUSY_HOUSE, HORIZON)
    fired = _events(trace)
    assert [e.event for e in fired] == ["relocate", "close", "breakdown", "new_target"] and all(
        e.applied for e in fired
    ), fired
    return trace


@pytest.fixture(scope="module")
def skipped(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A close at tick 1, when nothing can be open yet (the team has only navigated): skipped."""
    d = tmp_path_factory.mktemp("skipped")
    scenario = d / "nothing_open.json"
    scenario.write_text(json.dumps([{"tick": 1, "kind": "close"}]))
    trace = _record(d / "trace.jsonl", scenario, SKIP_HORIZON)
    fired = _events(trace)
    assert len(fired) == 1 and not fired[0].applied and fired[0].skipped, fired
    return trace


@pytest.fixture(scope="module")
def static(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_heuristic(tmp_path_factory.mktemp("static") / "trace.jsonl", horizon=4)


def _snapshot_rows(trace: Path) -> tuple[list[int], dict[int, int]]:
    """The trace positions of the snapshots, and of each scenario event by its index."""
    snaps, events = [], {}
    for n, r in enumerate(read_records(trace)):
        if isinstance(r.msg, Snapshot):
            snaps.append(n)
        elif isinstance(r.msg, ScenarioEvent):
            events[r.msg.index] = n
    return snaps, events


# --------------------------------------------------------------------------- the view model


def test_the_view_model_holds_each_event_at_the_first_frame_that_shows_it(busy: Path) -> None:
    view = build_view(load_trace(busy))
    fired = _events(busy)
    scenario = load_scenario(BUSY_HOUSE)
    assert view.header.scenario == ("busy_house", scenario.sha256)
    assert [(m.index, m.event, m.tick, m.applied, m.changed, m.text) for m in view.events] == [
        (e.index, e.event, e.tick, e.applied, e.changed, e.text) for e in fired
    ]
    snaps, rows = _snapshot_rows(busy)
    frames = view.frames
    by_kind = {m.event: m for m in view.events}
    at: dict[str, int] = {}
    for m in view.events:
        # the first snapshot recorded after the event: the world as the event's tick opens
        assert m.frame is not None and snaps[m.frame] > rows[m.index] > snaps[m.frame - 1]
        assert frames[m.frame].tick < m.tick <= frames[m.frame].tick + 1
        at[m.event] = m.frame

    move = by_kind["relocate"]
    obj, was, now = move.changed["object"], frames[at["relocate"] - 1].objects, frames[at["relocate"]].objects
    assert (was[obj].on, now[obj].on) == (move.changed["from"], move.changed["to"])
    assert move.at == (now[obj].x, now[obj].y) and move.origin == (was[obj].x, was[obj].y)

    added = by_kind["new_target"]
    new, there = added.changed["object"], frames[at["new_target"]].objects
    assert new not in frames[at["new_target"] - 1].objects and there[new].on == added.changed["on"]
    assert added.at == (there[new].x, there[new].y)

    close = by_kind["close"]
    box = close.changed["container"]
    assert frames[at["close"] - 1].open[box] and not frames[at["close"]].open[box]
    furniture = {f.name: f for f in view.scene.furniture} if view.scene else {}
    assert close.at == (furniture[box].x, furniture[box].y)

    broke = by_kind["breakdown"]
    assert (broke.robot, broke.until, broke.at) == ("david", 17, None)
    assert broke.caption == "tick 12: david broke down until tick 17: it can only communicate and wait"
    assert move.caption == f"tick {move.tick}: someone moved {obj} from {move.changed['from']} to {move.changed['to']}"


def test_a_static_episode_has_no_events_and_no_scenario(static: Path) -> None:
    view = build_view(load_trace(static))
    assert view.events == [] and view.header.scenario is None


# --------------------------------------------------------------------------- the HTML


class _Page(HTMLParser):
    """The report's event parts: timeline markers, lane entries (by lane), the header's facts."""

    def __init__(self) -> None:
        super().__init__()
        self.markers: list[dict[str, str]] = []
        self.entries: list[tuple[str, dict[str, str]]] = []  # (lane, attrs) of steps and events, in order
        self.facts: dict[str, str] = {}
        self.ids: set[str] = set()
        self.h1 = ""
        self._lane = ""
        self._th: str | None = None
        self._in: str | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        cls = a.get("class", "").split()
        if a.get("id"):
            self.ids.add(a["id"])
        if "lane" in cls:
            self._lane = a.get("data-robot") or a.get("data-lane") or "?"
        if "ev-marker" in cls:
            self.markers.append(a)
        if tag == "li" and ("lane-event" in cls or "step" in cls):
            self.entries.append((self._lane, a))
        self._in = tag if tag in ("th", "td", "h1") else None

    def handle_data(self, data: str) -> None:
        if self._in == "h1":
            self.h1 += data
        elif self._in == "th":
            self._th = data
        elif self._in == "td" and self._th is not None:
            self.facts.setdefault(self._th, data)
            self._th = None


def _page(trace: Path, out: Path) -> tuple[str, _Page]:
    result = show(str(trace), "--out", str(out))
    assert result.exit_code == 0, result.output
    html = out.read_text(encoding="utf-8")
    page = _Page()
    page.feed(html)
    return html, page


def test_the_report_marks_every_event_on_the_timeline_in_the_lanes_and_names_the_scenario(
    busy: Path, tmp_path: Path
) -> None:
    _, page = _page(busy, tmp_path / "busy.html")
    view = build_view(load_trace(busy))
    sha = load_scenario(BUSY_HOUSE).sha256
    assert page.facts["scenario"] == f"busy_house ({sha[:8]})" and "scenario busy_house" in page.h1

    # the timeline: one marker per event at its frame, its kind as class, its sentence as tooltip
    assert "event-track" in page.ids
    assert [(int(m["data-frame"]), m["data-event"], m["title"]) for m in page.markers] == [
        (e.frame, e.event, e.caption) for e in view.events
    ]
    assert [m["class"].split() for m in page.markers] == [["ev-marker", f"ev-{e.event}"] for e in view.events]
    assert len({m["style"] for m in page.markers}) == 4  # four frames, four places on the track

    # the lanes: the breakdown in david's lane, between his steps of ticks 11 and 12; the others in the world lane
    events = [(lane, a) for lane, a in page.entries if "lane-event" in a["class"]]
    assert [(lane, a["data-event"]) for lane, a in events] == [
        ("david", "breakdown"),
        ("world", "relocate"),
        ("world", "close"),
        ("world", "new_target"),
    ]
    david = [a for lane, a in page.entries if lane == "david"]
    k = next(i for i, a in enumerate(david) if "lane-event" in a["class"])
    assert int(david[k - 1]["data-tick"]) == 11 and int(david[k + 1]["data-tick"]) == 12
    assert david[k]["data-frame"] == str(next(e.frame for e in view.events if e.event == "breakdown"))

    # the page's data: each event where the map draws it
    html = (tmp_path / "busy.html").read_text(encoding="utf-8")
    data = json.loads(html.split('id="mhrc-data">', 1)[1].split("</script>", 1)[0])
    assert [(e["event"], e["frame"], e["at"], e["origin"]) for e in data["events"]] == [
        (e.event, e.frame, list(e.at) if e.at else None, list(e.origin) if e.origin else None) for e in view.events
    ]


def test_a_skipped_event_is_marked_skipped_with_why_and_a_static_report_has_no_event_parts(
    skipped: Path, static: Path, tmp_path: Path
) -> None:
    html, page = _page(skipped, tmp_path / "skipped.html")
    why = _events(skipped)[0].skipped
    [marker] = page.markers
    assert marker["class"].split() == ["ev-marker", "ev-close", "skipped"]
    assert marker["title"].startswith("tick 1: ") and "skipped" in marker["title"] and why in marker["title"]
    [(lane, entry)] = [(lane, a) for lane, a in page.entries if "lane-event" in a["class"]]
    assert lane == "world" and "skipped" in entry["class"].split()
    assert f"skipped: {why}" in html

    # a static episode's report: none of it (its page reads as it did before scenarios)
    html, page = _page(static, tmp_path / "static.html")
    assert not page.markers and "event-track" not in page.ids and "frame-events" not in page.ids
    assert not [a for _, a in page.entries if "lane-event" in a["class"]] and "scenario" not in page.facts
    assert '"events"' not in html.split('id="mhrc-data">', 1)[1].split("</script>", 1)[0]


# --------------------------------------------------------------------------- in a real browser


def _scrub(drv: Any, frame: int) -> None:
    from selenium.webdriver.common.by import By

    drv.execute_script(
        "const s = arguments[0]; s.value = arguments[1]; s.dispatchEvent(new Event('input', {bubbles: true}));",
        drv.find_element(By.ID, "tick-slider"),
        frame,
    )


def _centre(el: Any) -> tuple[float, float]:
    b = el.parent.execute_script(
        "const b = arguments[0].getBBox(); return [b.x + b.width / 2, b.y + b.height / 2];", el
    )
    return float(b[0]), float(b[1])


@pytest.mark.slow
def test_scrubbing_to_an_event_shows_its_markers_in_a_browser(driver: Any, busy: Path) -> None:
    from selenium.webdriver.common.by import By

    report = Path(show(str(busy)).output.strip().splitlines()[-1])
    driver.get(report.as_uri())
    assert not [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
    data = json.loads(driver.find_element(By.ID, "mhrc-data").get_attribute("textContent"))
    svg = driver.find_element(By.ID, "map")
    xmin, ymax, scale = (float(svg.get_attribute(f"data-{k}")) for k in ("xmin", "ymax", "scale"))
    frames = data["frames"]
    label = driver.find_element(By.ID, "tick-label")

    for ev in data["events"]:
        kind, frame = ev["event"], ev["frame"]
        # before the event: no marker on the map, its timeline marker not current
        _scrub(driver, frame - 1)
        assert not driver.find_elements(By.CSS_SELECTOR, f"#map g.ev-mark[data-index='{ev['index']}']"), kind
        marker = driver.find_element(By.CSS_SELECTOR, f".ev-marker[data-index='{ev['index']}']")
        assert marker.is_displayed() and "current" not in marker.get_attribute("class").split()

        # at the event's frame: the map marks where it happened, the timeline marker is current
        _scrub(driver, frame)
        assert label.get_attribute("data-frame") == str(frame)
        assert "current" in marker.get_attribute("class").split()
        [mark] = driver.find_elements(By.CSS_SELECTOR, f"#map g.ev-mark.ev-{kind}[data-index='{ev['index']}']")
        assert mark.is_displayed() and "fresh" in mark.get_attribute("class").split()
        assert ev["text"] in mark.find_element(By.TAG_NAME, "title").get_attribute("textContent")
        x, y = _centre(mark)
        if kind == "breakdown":  # on the robot, wherever it stands
            robot = frames[frame]["robots"][ev["robot"]]
            wx, wy = robot["x"], robot["y"]
            assert (
                "(broken down)" in driver.find_element(By.CSS_SELECTOR, f"#labels text[data-for='{ev['robot']}']").text
            )
        else:
            wx, wy = ev["at"]
        assert abs(x - (wx - xmin) * scale) < 16 and abs(y - (ymax - wy) * scale) < 16, (kind, x, y, wx, wy)
        if kind == "relocate":  # an arrow from the old place
            arrow = driver.find_element(By.CSS_SELECTOR, f"#map line.ev-arrow[data-index='{ev['index']}']")
            ox, oy = ev["origin"]
            assert (
                abs(float(arrow.get_attribute("x1")) - (ox - xmin) * scale) < 0.2
                and abs(float(arrow.get_attribute("y1")) - (ymax - oy) * scale) < 0.2
            )
        said = driver.find_element(By.ID, "frame-events").text
        assert ev["text"] in said

        # its lane entry is current
        entry = driver.find_element(By.CSS_SELECTOR, f".lane-event[data-index='{ev['index']}']")
        assert "current" in entry.get_attribute("class").split()

    # later: fixed markers stay (no longer fresh); the breakdown is gone once the robot works again
    _scrub(driver, len(frames) - 1)
    kinds = sorted(g.get_attribute("data-event") for g in driver.find_elements(By.CSS_SELECTOR, "#map g.ev-mark"))
    assert kinds == ["close", "new_target", "relocate"] and not driver.find_elements(
        By.CSS_SELECTOR, "#map g.ev-mark.fresh"
    )

    # a click on a timeline marker jumps to its frame
    first = data["events"][0]
    driver.find_element(By.CSS_SELECTOR, f".ev-marker[data-index='{first['index']}']").click()
    assert label.get_attribute("data-frame") == str(first["frame"])

    # the markers under the slider run in frame order, inside the slider's width
    slider = driver.find_element(By.ID, "tick-slider")
    left, width = slider.location["x"], slider.size["width"]
    xs = [m.location["x"] + m.size["width"] / 2 for m in driver.find_elements(By.CSS_SELECTOR, ".ev-marker")]
    assert xs == sorted(xs) and all(left <= x <= left + width for x in xs)
    assert not [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]


# --------------------------------------------------------------------------- the video


def test_the_video_captions_each_event_at_the_frames_of_its_tick(busy: Path, static: Path) -> None:
    from mhrc.viewer.video import _Captioner  # the caption band alone: no scene rendered

    started, steps, named = read_episode(busy)
    shown: dict[str, list[int]] = {}
    for ev in _events(busy):
        text = ev.text.rstrip(".")
        said = f"tick {ev.tick}: {text[0].lower() + text[1:] if text[1].islower() else text}"
        shown[ev.event] = [i for i, s in enumerate(steps) if said in s.events]
        # from the first snapshot after the event (the world as its tick opens) through its tick's own
        assert [steps[i].snapshot.tick for i in shown[ev.event]] == [ev.tick - 1, ev.tick], (said, shown)
    moved = steps[shown["relocate"][-1]]
    assert moved.events == ("tick 6: someone moved {object} from {from} to {to}".format(**_events(busy)[0].changed),)
    quiet = [s for s in steps if not s.events]
    assert len(quiet) == len(steps) - 2 * len(shown)

    # the caption band has a line for them, drawn at those frames only
    cap = _Captioner(320, 240, started, len(steps), events=True)
    assert cap.band == _Captioner(320, 240, started, len(steps)).band + cap.line
    picture = np.zeros((240 - cap.band, 320, 3), dtype=np.uint8)
    line = slice(240 - 3 - cap.line // 2 - cap.line, 240 - 3 - cap.line // 2)

    def lit(step: Any) -> int:  # pixels of the events' colour (mhrc.viewer.video.EVENT) in their line
        px = cap.compose(picture, 1, step, 0.5)[line].astype(int)
        return int(((px[:, :, 0] > 200) & (px[:, :, 1] > 170) & (px[:, :, 2] < 150)).sum())

    assert lit(moved) > 50 and lit(quiet[-1]) == 0
    _, plain, unnamed = read_episode(static)
    assert not any(s.events or s.added for s in plain)
    # the title names the scenario (name and hash), a static episode's none
    sha = _events(busy)[0].sha256
    assert named == f"busy_house ({sha[:8]})" and unnamed is None
    assert _Captioner(320, 240, started, len(steps), scenario=named).title.endswith(
        f"/ scenario busy_house ({sha[:8]})"
    )


def test_the_videos_own_sim_gets_the_new_target_from_its_first_snapshot(busy: Path) -> None:
    """The video rebuilds the scene from the episode's start: a new target must join it at its frame."""
    from mhrc.viewer.video import _spawns

    started, steps, _ = read_episode(busy)
    added = next(e for e in _events(busy) if e.event == "new_target").changed
    [(first, obj)] = [(i, a) for i, s in enumerate(steps) for a in s.added]
    assert obj == (added["object"], added["on"]) and added["object"] in steps[first].snapshot.objects
    assert added["object"] not in steps[first - 1].snapshot.objects
    with Sim(
        task=started.task, scene=started.scene, seed=started.seed, n_objects=started.n_objects, scenario=_spawns(steps)
    ) as sim:
        sim.fire_events(first - 1)
        assert added["object"] not in sim.world.objects
        sim.fire_events(first)
        assert added["object"] in sim.world.objects
