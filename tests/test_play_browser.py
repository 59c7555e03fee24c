"""`mhrc play` in a real headless chromium (selenium, as the report's browser tests): a person
plays David beside the heuristic Alice and Bob to a successful episode, and Alice picks and
places. Each world is one `mhrc play` process on a secured loopback bus; one scripted browser
session per world collects what the checks below assert on. Before David's player opens the
page, a page of another origin, a rebound Host and a socket without the secret try it first.

Set MHRC_PLAY_SCREENSHOT=PATH to keep the first screenshot (docs/play.png is taken so), and
Alice's page after she placed the book beside it (PATH's stem + "-alice.png")."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, TypeVar

import pytest
from test_play_gate import Page, play_page  # noqa: F401  (the page's server alone, no world: for the map's drawing)
from test_viewer_browser import browser, chrome  # noqa: F401  (the fixture: Debian's chromium and chromedriver)
from waits import until_sync

from mhrc.core.protocol import ActionResult, EpisodeDone, RobotAttached, RobotDetached, RobotMessage, Thought
from mhrc.core.records import messages, read_records

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("play_browser")]

M = TypeVar("M")
WAIT = 60.0  # s for anything the page or the world should do


@dataclass
class Played:
    """One `mhrc play` run and what its page showed."""

    tmp: Path
    proc: subprocess.Popen[bytes]
    url: str = ""
    facts: dict[str, Any] = field(default_factory=dict)
    world: subprocess.Popen[bytes] | None = None  # `mhrc up --external ROBOT`, for a page that joins a world elsewhere

    @property
    def trace(self) -> Path:
        return self.tmp / "trace.jsonl"

    @property
    def out(self) -> str:
        return (self.tmp / "out.txt").read_text()

    def of(self, model: type[M]) -> list[M]:
        """The trace's messages of `model` so far (none while its last line is half written)."""
        try:
            return messages(read_records(self.trace), model)
        except (OSError, ValueError):
            return []


def _start(tmp: Path, name: str, *args: str) -> subprocess.Popen[bytes]:
    with (tmp / f"{name}.txt").open("wb") as out, (tmp / f"{name}-err.txt").open("wb") as err:
        return subprocess.Popen([sys.executable, "-m", "mhrc", *args], cwd=tmp, stdout=out, stderr=err)


def _play(tmp: Path, robot: str, *args: str, world: subprocess.Popen[bytes] | None = None) -> Played:
    """`mhrc play` for `robot` (with `args`), once its page's address is printed."""
    trace = [] if world is not None else ["--trace", str(tmp / "trace.jsonl")]
    proc = _start(tmp, "out", "play", "--robot", robot, "--no-browser", *trace, *args)
    played = Played(tmp, proc, world=world)
    until_sync(lambda: "http://" in played.out or proc.poll() is not None, "the page's address", WAIT)
    match = re.search(r"http://127\.0\.0\.1:\d+/\?token=[\w-]+", played.out)
    assert match, (played.out, (tmp / "out-err.txt").read_text())
    played.url = match.group(0)
    return played


def _joining(tmp: Path, robot: str, *args: str) -> Played:
    """A world started elsewhere (`mhrc up --external ROBOT`) and `mhrc play --connect` with the
    robot's credentials, as `mhrc up` says to attach it."""
    world = _start(tmp, "world", "up", "--external", robot, "--trace", str(tmp / "trace.jsonl"), *args)
    said = tmp / "world.txt"
    until_sync(lambda: "mhrc agent --robot" in said.read_text() or world.poll() is not None, "the attach line", WAIT)
    line = re.search(r"mhrc agent --robot \S+ --run (\S+) --connect (\S+) --credentials (\S+)", said.read_text())
    assert line, said.read_text()
    run, endpoint, login = line.groups()
    return _play(tmp, robot, "--run", run, "--connect", endpoint, "--credentials", login, world=world)


def _stop(played: Played) -> None:
    for proc in (played.proc, played.world):
        if proc is None or proc.poll() is not None:
            continue
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _css(drv: Any, selector: str) -> Any:
    from selenium.webdriver.common.by import By

    return drv.find_element(By.CSS_SELECTOR, selector)


def _status(drv: Any) -> tuple[str, int | None]:
    el = _css(drv, "[data-status]")
    tick = el.get_attribute("data-tick")
    return el.get_attribute("data-status"), int(tick) if tick else None


def _deciding(drv: Any, after: int = -1) -> int:
    """Wait for the page to ask for a decision on a tick after `after`; the tick."""
    until_sync(
        lambda: _status(drv)[0] == "deciding" and (_status(drv)[1] or 0) > after,
        f"the page to ask for a decision after tick {after}",
        WAIT,
    )
    return _status(drv)[1] or 0


def _submit(drv: Any, skill: str, **values: str) -> None:
    from selenium.webdriver.support.ui import Select

    form = _css(drv, f'form[data-skill="{skill}"]')
    for name, value in values.items():
        el = form.find_element("css selector", f'[name="{name}"]')
        if el.tag_name == "select":
            Select(el).select_by_value(value)
        else:
            el.clear()
            el.send_keys(value)
    form.find_element("css selector", "[data-submit]").click()


def _refused(drv: Any, code: str) -> str:
    until_sync(lambda: _css(drv, "[data-refusal]").get_attribute("data-code") == code, f"a {code} refusal", WAIT)
    return _css(drv, "[data-refusal]").get_attribute("data-refusal")


# Every text of the map: the pairs whose boxes overlap on screen, and the smallest one's size on screen.
LABELS_JS = """
const ts = [...document.querySelectorAll('#map text')].filter(t => t.textContent);
const box = t => t.getBoundingClientRect();
const out = {n: ts.length, overlaps: [], min_px: 1e9};
ts.forEach((a, i) => {
  out.min_px = Math.min(out.min_px, parseFloat(getComputedStyle(a).fontSize) * a.getScreenCTM().a);
  const p = box(a);
  for (const b of ts.slice(i + 1)){
    const q = box(b);
    if (p.left < q.right && q.left < p.right && p.top < q.bottom && q.top < p.bottom) out.overlaps.push([a.textContent, b.textContent]);
  }
});
return out;
"""


def _labels(drv: Any, into: dict[str, Any]) -> None:
    """Fold the map's labels now into `into` (every overlap seen, the smallest size seen)."""
    now = drv.execute_script(LABELS_JS)
    into.setdefault("overlaps", []).extend(now["overlaps"])
    into["min_px"] = min(into.get("min_px", 1e9), now["min_px"])
    into["most"] = max(into.get("most", 0), now["n"])


def _rect(drv: Any, selector: str) -> tuple[float, float, float, float]:
    r = _css(drv, selector).rect
    return r["x"], r["y"], r["width"], r["height"]


ANOTHER_ORIGIN = """<!doctype html><title>another origin</title><script>
window.seen = [];
function probe(name, url){
  const ws = new WebSocket(url);
  ws.onopen = () => { seen.push(name + ':open'); ws.send(JSON.stringify({type: 'submit', tick: 0, skill: 'wait'})); };
  ws.onmessage = () => seen.push(name + ':message');
  ws.onclose = () => seen.push(name + ':close');
}
probe('with_secret', WITH_SECRET);
probe('without', WITHOUT);
</script>"""


@contextlib.contextmanager
def _another_origin(page: str) -> Iterator[str]:
    """A tiny site on another loopback port serving `page`; its address."""

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802
            body = page.encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: Any) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(10)


def _hostile_first(drv: Any, played: Played) -> dict[str, Any]:
    """Before the player opens the page: a page of another origin opens the robot's socket (with
    the secret and without), a rebound Host asks for the page, a plain socket comes without the
    secret. What each got."""
    import httpx
    import websocket

    token = played.url.split("token=")[1]
    ws = played.url.replace("http://", "ws://").replace("/?token=", "/ws?token=")
    got: dict[str, Any] = {}
    page = ANOTHER_ORIGIN.replace("WITH_SECRET", json.dumps(ws)).replace("WITHOUT", json.dumps(ws.split("?")[0]))
    with _another_origin(page) as elsewhere:
        drv.get(elsewhere)
        until_sync(
            lambda: len([e for e in drv.execute_script("return window.seen") if e.endswith(":close")]) == 2,
            "the other origin's sockets to close",
            WAIT,
        )
        got["another_origin"] = drv.execute_script("return window.seen")
    rebound = httpx.get(played.url, headers={"Host": "evil.example"}, timeout=10)
    got["rebound"] = (rebound.status_code, "observation" in rebound.text)
    try:
        websocket.create_connection(ws.split("?")[0], origin=played.url.split("/?")[0], timeout=10).close()
        got["plain_socket"] = "accepted"
    except websocket.WebSocketBadStatusException as exc:
        got["plain_socket"] = exc.status_code
    got["token"] = token
    return got


def _world_state_answers(played: Played, user: str) -> int:
    """How many answers a session logged in as `user` gets to a world/state query."""
    from mhrc.core.bus import open_client
    from mhrc.core.keys import Keys
    from mhrc.core.security import load

    creds = load(played.tmp / "credentials" / f"{user}.json")
    endpoint = re.search(r"world on (\S+),", played.out)
    assert endpoint, played.out

    async def ask() -> int:
        bus = await open_client(endpoint.group(1), 10.0, security=creds)
        try:
            return len(await bus.get(Keys(creds.run).world_state, timeout=2.0))
        finally:
            await bus.close()

    return asyncio.run(ask())


@pytest.fixture(scope="module")
def david(browser: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Played]:  # noqa: F811
    """A person plays David: bad input first, a second tab, navigate, message Alice, the tab
    closed mid-episode and opened again, then wait (the key w, and r to repeat) to the end."""
    from selenium.webdriver.common.action_chains import ActionChains

    played = _play(
        tmp_path_factory.mktemp("play-david"),
        "david",
        "--objects",
        "3",
        "--seed",
        "0",
        "--tick-delay",
        "0.4",
        "--log-level",
        "info",
    )
    facts = played.facts
    labels: dict[str, Any] = {}
    facts["labels"] = labels
    drv = chrome(browser, "1400,1400")
    try:
        facts["hostile"] = _hostile_first(drv, played)
        drv.get(played.url)
        tick = _deciding(drv)
        _labels(drv, labels)
        facts["observation"] = _css(drv, '[data-panel="observation"]').text
        facts["forms"] = [f.get_attribute("data-skill") for f in drv.find_elements("css selector", "form[data-skill]")]
        facts["map_furniture"] = len(drv.find_elements("css selector", "#map [data-name]"))
        facts["state_answers"] = {u: _world_state_answers(played, u) for u in ("david", "observer")}
        # bad input: refused on the page with the reason, the decision stays open
        drv.execute_script("window.mhrcPlay.send({tick: arguments[0], skill: 'wait'})", tick - 1 if tick else 99)
        facts["stale"] = _refused(drv, "stale_tick")
        drv.execute_script(
            "window.mhrcPlay.send({tick: arguments[0], skill: 'navigate', target: 'garage', stand_pose: '0'})", tick
        )
        facts["not_a_choice"] = _refused(drv, "not_a_choice")
        _submit(drv, "communicate", to="alice", content="x" * 4500)
        facts["oversized"] = _refused(drv, "malformed")
        facts["after_bad_input"] = _status(drv)
        # a second tab for the same robot is refused
        first = drv.current_window_handle
        drv.switch_to.new_window("tab")
        drv.get(played.url)
        until_sync(lambda: _status(drv)[0] == "refused", "the second tab's refusal", WAIT)
        facts["second_tab"] = _css(drv, "[data-refusal]").get_attribute("data-refusal")
        drv.close()
        drv.switch_to.window(first)
        # navigate, then message Alice
        _submit(drv, "navigate", target="sofa", stand_pose="1")
        tick = _deciding(drv, tick)
        facts["feedback_after_navigate"] = _css(drv, '[data-section="feedback"]').text
        _submit(drv, "communicate", to="alice", content="Alice, David here: I am at the sofa.")
        tick = _deciding(drv, tick)
        shot = played.tmp / "play.png"  # the page two decisions in: the map, the histories, the forms
        drv.save_screenshot(str(shot))
        if keep := os.environ.get("MHRC_PLAY_SCREENSHOT"):
            shutil.copy(shot, keep)
        _labels(drv, labels)
        facts["layout"] = {
            k: _rect(drv, k) for k in ("#map", '[data-panel="messages"]', '[data-section="scene_graph"]')
        }
        # a reload mid-turn: the page attaches again to the same pending tick, and acts on it
        drv.refresh()
        facts["reload"] = (tick, _deciding(drv, tick - 1))
        _submit(drv, "wait")
        tick = _deciding(drv, tick)
        # the tab closed mid-episode: the robot is detached; the page opened again attaches it again
        drv.switch_to.new_window("tab")
        blank = drv.current_window_handle
        drv.switch_to.window(first)
        drv.close()
        drv.switch_to.window(blank)
        until_sync(lambda: any(d.robot == "david" for d in played.of(RobotDetached)), "david detached", WAIT)
        drv.get(played.url)
        tick = _deciding(drv, tick - 1)
        facts["reattached_at"] = tick
        # wait (w) and repeat (r) to the end
        keys, answered = 0, -1
        while _status(drv)[0] != "done":
            state, now = _status(drv)
            if state == "deciding" and now != answered:
                answered = now if now is not None else -1
                _labels(drv, labels)
                drv.execute_script("document.activeElement && document.activeElement.blur()")
                ActionChains(drv).send_keys("r" if keys == 1 else "w").perform()
                keys += 1
            until_sync(
                lambda: _status(drv)[0] == "done" or (_status(drv)[0] == "deciding" and _status(drv)[1] != answered),
                f"the next decision or the end (after {keys} keys, the page says {_css(drv, '[data-status]').text!r})",
                WAIT,
            )
        facts["keys"] = keys
        facts["end"] = (_css(drv, "[data-status]").get_attribute("data-success"), _css(drv, "[data-status]").text)
        facts["messages_panel"] = _css(drv, '[data-panel="messages"]').text
        played.proc.wait(WAIT)
        yield played
    finally:
        drv.quit()
        _stop(played)


def test_a_person_plays_david_beside_heuristic_teammates_to_success(david: Played) -> None:
    f = david.facts
    assert f["end"][0] == "yes", f["end"]
    assert david.proc.returncode == 0, (david.tmp / "out-err.txt").read_text()[-2000:]
    done = david.of(EpisodeDone)[-1]
    assert done.reason == "success"
    calls = [r.action.call() for r in david.of(ActionResult) if r.robot == "david"]
    assert calls[0] == "navigate(sofa, 1)" and calls[1].startswith("communicate('Alice, David here")
    assert set(calls[2:]) == {"wait()"} and f["keys"] >= 2
    alice_heard = [m for m in david.of(RobotMessage) if m.sender == "david" and m.to == "alice"]
    assert alice_heard and "at the sofa" in alice_heard[0].content
    assert re.search(r"david \(you\): \d+ actions \(\d+%\), 0 moves \(0%\), 1 messages", david.out), david.out


def test_the_page_shows_the_robots_own_observation_and_its_skills(david: Played) -> None:
    f = david.facts
    assert "You are" not in f["observation"] and "Brief: Search the whole house" in f["observation"]
    assert "table_0: position (-2.90, 0.00, 0.70)" in f["observation"]
    assert f["forms"] == ["navigate", "communicate", "wait"]  # David has no arm
    assert f["map_furniture"] > 5
    assert (
        "navigate(sofa, 1) succeeded" in f["feedback_after_navigate"]
        or "navigate(sofa, 1) FAILED" in f["feedback_after_navigate"]
    )


def test_the_human_decisions_are_thoughts_with_policy_human_and_their_latency(david: Played) -> None:
    thoughts = [t for t in david.of(Thought) if t.robot == "david"]
    assert thoughts and {t.policy for t in thoughts} == {"human"}
    assert all(t.latency > 0 for t in thoughts) and all(t.prompt is None for t in thoughts)


def test_bad_input_is_refused_on_the_page_with_the_reason_and_the_episode_goes_on(david: Played) -> None:
    f = david.facts
    assert "the request is for tick" in f["stale"]
    assert "target 'garage' is not one of the choices" in f["not_a_choice"]
    assert "4000" in f["oversized"]
    assert f["after_bad_input"][0] == "deciding"


def test_a_page_of_another_origin_cannot_drive_the_robot(david: Played) -> None:
    """Its sockets, with the secret and without, are refused at the handshake: never open, no
    message heard; the player who came after it drives David (his first action is the player's)."""
    seen = david.facts["hostile"]["another_origin"]
    assert sorted(seen) == ["with_secret:close", "without:close"], seen
    first = next(r for r in david.of(ActionResult) if r.robot == "david")
    assert first.action.call() == "navigate(sofa, 1)"


def test_a_rebinding_host_and_a_socket_without_the_secret_are_refused(david: Played) -> None:
    hostile = david.facts["hostile"]
    assert hostile["rebound"] == (400, False)
    assert hostile["plain_socket"] == 403


def test_the_secret_is_in_no_log_and_not_in_the_trace(david: Played) -> None:
    token = david.facts["hostile"]["token"]
    logs = (david.tmp / "out-err.txt").read_text()
    assert "request refused" in logs and "code=origin" in logs  # the refusals were logged, at --log-level info
    assert token not in logs and token not in david.trace.read_text()
    assert david.out.count(token) == 1  # the printed address, once


def test_a_reload_keeps_the_players_turn(david: Played) -> None:
    """Reloaded mid-turn, the page shows the same pending tick, and the action chosen after the
    reload is David's action of that tick; the robot was never detached by the reload."""
    before, after = david.facts["reload"]
    assert after == before
    acted = [r for r in david.of(ActionResult) if r.robot == "david" and r.tick == before]
    assert [r.action.call() for r in acted] == ["wait()"]
    detached = [d for d in david.of(RobotDetached) if d.robot == "david"]
    assert all(d.tick > before for d in detached), detached


def test_messages_sit_beside_the_map_above_the_scene_graph(david: Played) -> None:
    layout = david.facts["layout"]
    mx, my, mw, mh = layout["#map"]
    x, y, _, _ = layout['[data-panel="messages"]']
    assert x >= mx + mw and my <= y < my + mh, layout
    assert y < layout['[data-section="scene_graph"]'][1]


def test_the_end_status_reads_once(david: Played) -> None:
    text = david.facts["end"][1]
    assert text.startswith("the episode is over: success, ") and text.count("success") == 1, text


@pytest.mark.parametrize(("who", "least"), [("david", 15), ("alice", 16)])
def test_the_maps_labels_are_readable_and_never_overlap(who: str, least: int, request: pytest.FixtureRequest) -> None:
    """Every label of the map (furniture and the objects the robot knows), at every decision
    David saw and after Alice placed the book on table_0: none overlaps another, none is smaller
    than 12 px on screen."""
    labels = request.getfixturevalue(who).facts["labels"]
    assert labels["overlaps"] == [] and labels["min_px"] >= 12, labels
    assert labels["most"] >= least  # the 15 pieces of furniture's, and Alice's objects'


def test_a_second_tab_for_the_robot_is_refused(david: Played) -> None:
    assert "one driver per robot" in david.facts["second_tab"]


def test_closing_the_tab_detaches_the_robot_and_reopening_attaches_it_again(david: Played) -> None:
    attached = [a for a in david.of(RobotAttached) if a.robot == "david"]
    detached = [d for d in david.of(RobotDetached) if d.robot == "david"]
    assert len(detached) == 1 and len(attached) == 2 and attached[0].agent_id != attached[1].agent_id
    assert detached[0].tick >= 2 and david.facts["reattached_at"] >= detached[0].tick


def test_the_pages_server_never_gets_world_state(david: Played) -> None:
    """The page's server logs in as its robot; the world's access control answers that login no
    `world/state` (the observer's login, asked the same, is answered)."""
    assert david.facts["state_answers"] == {"david": 0, "observer": 1}


@pytest.fixture(scope="module")
def alice(browser: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Played]:  # noqa: F811
    """A person plays Alice of a world started elsewhere (`mhrc play --connect`, her credentials):
    go to Bob's table, pick the book lying beyond his reach, place it."""
    played = _joining(tmp_path_factory.mktemp("play-alice"), "alice", "--objects", "3", "--seed", "0", "--noise", "off")
    facts = played.facts
    drv = chrome(browser, "1400,1400")
    try:
        drv.get(played.url)
        tick = _deciding(drv)
        facts["map_scene"] = _css(drv, "#map").get_attribute("data-scene")
        place = _css(drv, 'form[data-skill="place"]')
        facts["place_disabled"] = (
            place.get_attribute("data-disabled"),
            place.find_element("css selector", "[data-why]").text,
            place.find_element("css selector", "[data-submit]").is_enabled(),
        )
        _submit(drv, "navigate", target="table_0", stand_pose="2")
        tick = _deciding(drv, tick)
        _submit(drv, "pick", object="book")
        tick = _deciding(drv, tick)
        facts["holding"] = _css(drv, '[data-section="status"]').text
        _submit(drv, "navigate", target="table_0", stand_pose="0")
        tick = _deciding(drv, tick)
        _submit(drv, "place", object="book", location="table_0")
        _deciding(drv, tick)
        facts["labels"] = {}
        _labels(drv, facts["labels"])
        if keep := os.environ.get("MHRC_PLAY_SCREENSHOT"):  # Alice's map, the objects she knows on it
            drv.save_screenshot(str(Path(keep).with_name(Path(keep).stem + "-alice.png")))
        yield played
    finally:
        drv.quit()
        _stop(played)


def test_a_person_plays_alice_and_picks_and_places_an_object(alice: Played) -> None:
    results = {r.action.call(): r.outcome.succeeded for r in alice.of(ActionResult) if r.robot == "alice"}
    assert results.get("pick(book)") is True and results.get("place(book, table_0)") is True, results
    assert "holding book" in alice.facts["holding"]
    assert alice.facts["map_scene"] == "kitchen"  # told nothing of the world's scene, the page found its layout


def test_a_disabled_control_says_why(alice: Played) -> None:
    reason, shown, enabled = alice.facts["place_disabled"]
    assert reason == "your gripper is empty: pick something first" and shown == reason and not enabled


def test_the_report_marks_the_human_lane(david: Played) -> None:
    """`mhrc show` of the episode: David's lane says a person played it, and how long each decision took."""
    from click.testing import CliRunner

    from mhrc.cli import main

    result = CliRunner().invoke(main, ["show", str(david.trace)])
    assert result.exit_code == 0, result.output
    page = Path(result.output.strip().splitlines()[-1]).read_text()
    lanes = dict(re.findall(r'<div class="lane([^"]*)" data-robot="(\w+)"', page)[i][::-1] for i in range(3))
    assert lanes == {"alice": "", "bob": "", "david": " human"}
    assert page.count("data-human>") == 1 and "decided by a person in" in page


def test_labels_of_objects_on_furniture_and_stacked_never_overlap(
    play_page: Page,  # noqa: F811
    browser: tuple[Path, Path],  # noqa: F811
) -> None:
    """The map of an observation (no world: the page's own drawing, `mhrcPlay.show`): a mug on
    table_2 (its place pose 15 cm from the table's centre, where the table's name is, as the mug
    sat over table_3's name), three objects stacked on the tray, soap on table_0 beside the tray.
    Every name reads, none over another."""
    from mhrc.play.house import house_svg
    from mhrc.play.human import HumanPolicy
    from mhrc.testing.policy_harness import observation

    obs = observation(
        "alice", objects={"mug": "table_2", "apple": "tray", "bowl": "tray", "plate": "tray", "soap": "table_0"}
    )
    policy = HumanPolicy("alice")
    policy.house = lambda o: ("kitchen", house_svg("kitchen", o))
    policy.obs = obs
    view = json.dumps(policy.view())
    drv = chrome(browser, "1400,1100")
    try:
        drv.get(play_page.gate.url)
        until_sync(lambda: drv.execute_script("return !!window.mhrcPlay"), "the page's script", WAIT)
        drv.execute_script("window.mhrcPlay.show(JSON.parse(arguments[0]))", view)
        labels: dict[str, Any] = {}
        _labels(drv, labels)
        names = set(drv.execute_script("return [...document.querySelectorAll('#map text')].map(t => t.textContent)"))
    finally:
        drv.quit()
    assert {"mug", "apple", "bowl", "plate", "soap", "table_2", "table_0"} <= names
    assert labels["overlaps"] == [] and labels["min_px"] >= 12, labels
