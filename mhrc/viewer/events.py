"""A dynamic episode's scenario events (issue 25) as the report and the video show them.

The world publishes a `scenario_event` on `world/event` when an event of the episode's
scenario fires (mhrc.world.dynamics): what it changed, or why it was skipped. An event of tick
T fires as tick T opens, so the first `snapshot` after it in the trace (lockstep: the one of
tick T - 1, taken once tick T's events applied) is the first map frame that shows it; that
frame is the event's place on the timeline, and the map keeps its marker from there on.

Where an event happened, in world metres: a relocated object's new place and the place it was
taken from (its position in the frame before; else its old surface's centre), a new target's
place, a closed container's centre; a breakdown is drawn on its robot, wherever it stands,
while it is broken down.
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass
from typing import TypedDict

from mhrc.core.protocol import ObjectPose, ScenarioEvent, Snapshot
from mhrc.viewer.frames import Frame
from mhrc.viewer.load import LoadedTrace
from mhrc.viewer.scene_map import SceneMap

KINDS = ("relocate", "new_target", "close", "breakdown")
# each kind's mark, the same on the timeline, the map's legend and the lanes
GLYPHS = {"relocate": "\u25c6", "new_target": "\u2605", "close": "\u25a0", "breakdown": "\u25b2"}
NAMES = {"relocate": "moved", "new_target": "added", "close": "closed", "breakdown": "broken down"}


class MarkData(TypedDict):
    """A scenario event as the page's script draws it (`ScenarioMark.as_data`)."""

    index: int
    event: str
    tick: int
    applied: bool
    skipped: str | None
    changed: dict[str, str]
    text: str  # its caption
    frame: int | None
    robot: str | None
    until: int | None
    at: list[float] | None
    origin: list[float] | None
    label: str


@dataclass
class ScenarioMark:
    """One fired scenario event, placed in time (a map frame) and, when it has one, in space."""

    index: int
    event: str  # relocate, breakdown, new_target, close
    tick: int
    applied: bool
    skipped: str | None
    changed: dict[str, str]
    text: str
    scenario: str
    sha256: str
    frame: int | None = None  # the first map frame that shows it
    at: tuple[float, float] | None = None  # where it happened (None: nowhere on the map, or on a robot)
    origin: tuple[float, float] | None = None  # a relocation's old place
    robot: str | None = None  # a breakdown's robot
    until: int | None = None  # a breakdown's end (exclusive tick)

    @property
    def caption(self) -> str:
        """`tick 6: someone moved mug from table_3 to tub`: the line the video and the tooltips show."""
        return caption(self.tick, self.text)

    def as_data(self) -> MarkData:
        """What the page's script draws it from."""
        return {
            "index": self.index,
            "event": self.event,
            "tick": self.tick,
            "applied": self.applied,
            "skipped": self.skipped,
            "changed": self.changed,
            "text": self.caption,
            "frame": self.frame,
            "robot": self.robot,
            "until": self.until,
            "at": list(self.at) if self.at else None,
            "origin": list(self.origin) if self.origin else None,
            "label": self.label,
        }

    @property
    def label(self) -> str:
        """A few words for the map beside the marker: `mug moved`, `cabinet_1 closed`."""
        what = self.changed.get("object") or self.changed.get("container") or self.changed.get("robot") or ""
        return f"{what} {NAMES.get(self.event, self.event)}".strip()


def caption(tick: int, text: str) -> str:
    """An event's sentence after its tick, as a caption: `tick 6: someone moved mug from table_3 to tub`."""
    body = " ".join(text.split()).rstrip(".")
    if len(body) > 1 and body[0].isupper() and body[1].islower():
        body = body[0].lower() + body[1:]
    return f"tick {tick}: {body}" if body else f"tick {tick}"


def scenario_name(marks: list[ScenarioMark]) -> tuple[str, str] | None:
    """(name, sha256) of the episode's scenario, from its events (episode_started does not carry it)."""
    for m in marks:
        return m.scenario, m.sha256
    return None


def scenario_label(name: str, sha256: str) -> str:
    """`busy_house (d45b5975)`: how the report's header and the video's title name a scenario."""
    return f"{name} ({sha256[:8]})" if sha256 else name


def _xy(pose: ObjectPose | None) -> tuple[float, float] | None:
    return (pose.x, pose.y) if pose is not None else None


def _centre(scene: SceneMap | None, name: str | None) -> tuple[float, float] | None:
    return scene.centre(name) if scene is not None else None


def scenario_marks(
    trace: LoadedTrace, frames: list[Frame], frames_from: str, scene: SceneMap | None
) -> list[ScenarioMark]:
    """Every scenario event of the trace, in trace order, with its frame and place."""
    snap_rows: list[int] = []
    found: list[tuple[int, ScenarioEvent]] = []
    for i, line in enumerate(trace.records):
        if isinstance(line.msg, Snapshot):
            snap_rows.append(i)
        elif isinstance(line.msg, ScenarioEvent):
            found.append((i, line.msg))
    marks = []
    for at, msg in found:
        m = ScenarioMark(
            index=msg.index,
            event=msg.event,
            tick=msg.tick,
            applied=msg.applied,
            skipped=msg.skipped,
            changed=dict(msg.changed),
            text=msg.text,
            scenario=msg.scenario,
            sha256=msg.sha256,
        )
        if frames_from == "snapshots":
            first = bisect_right(snap_rows, at)
            m.frame = first if first < len(frames) else None
        else:  # no snapshots (an older trace): the first frame at or after its tick
            m.frame = next((k for k, f in enumerate(frames) if f.tick >= m.tick), None)
        if m.applied:
            _place(m, frames, scene)
        marks.append(m)
    return marks


def _place(m: ScenarioMark, frames: list[Frame], scene: SceneMap | None) -> None:
    c = m.changed
    if m.event == "breakdown":
        m.robot = c.get("robot")
        try:
            m.until = int(c["until"])
        except (KeyError, ValueError):
            m.until = None
        return
    if m.event == "close":
        m.at = _centre(scene, c.get("container"))
        return
    obj = c.get("object")
    if m.frame is not None:
        m.at = _xy(frames[m.frame].objects.get(obj or ""))
    if m.at is None:
        m.at = _centre(scene, c.get("to") or c.get("on"))
    if m.event == "relocate":
        before = _xy(frames[m.frame - 1].objects.get(obj or "")) if m.frame else None
        m.origin = before or _centre(scene, c.get("from"))


def captions_by_snapshot(events: list[tuple[int, int, str]], snapshots: list[tuple[int, int]]) -> list[list[str]]:
    """For each snapshot ((trace position, tick), in order), the captions of the events it shows.
    `events` are (trace position, tick, caption). An event shows from the first snapshot after it in
    the trace through the last one of its own tick, or of that first snapshot's tick when it is
    later, and on two snapshots at least (async: one snapshot per action, so a caption stays up
    long enough to read)."""
    out: list[list[str]] = [[] for _ in snapshots]
    rows = [r for r, _ in snapshots]
    for row, tick, text in events:
        first = bisect_right(rows, row)
        if first == len(snapshots):
            continue
        until = max(tick, snapshots[first][1])
        for k in range(first, len(snapshots)):
            if snapshots[k][1] > until and k > first + 1:
                break
            out[k].append(text)
    return out
