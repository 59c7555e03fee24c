"""An episode's video, from its trace alone (plus the scene data).

The world publishes a `snapshot` event at the start and after every executed batch of
actions (ground truth: robot bases, objects, containers). The video rebuilds the episode's
scene (same task, scene, seed, object count and aids), teleports the bodies to each
snapshot in turn (`Sim.apply_snapshot`; no physics, arms stay in their home pose), renders
each with PyBullet's CPU renderer and captions it with what every robot did in that batch
and how it went, and, in a dynamic episode, with its scenario's events (mhrc.viewer.events: from
the first snapshot after an event through the last of its tick, e.g. "tick 6: someone moved mug
from table_3 to tub"). Between two snapshots the robots' bases glide in a straight line (not
along their planned paths: a robot may cross a wall between two frames).

Frame count: `frames_per_step` frames per snapshot, the first one held still; so
`len(snapshots) * frames_per_step` frames in all. The file type follows the suffix: `.mp4`
(H.264 through imageio's ffmpeg plugin) or `.gif` (Pillow). Pillow merges identical
consecutive GIF frames into one longer frame; the progress bar along the bottom keeps frames
apart as long as there are no more frames than pixels across.
"""

from __future__ import annotations

import math
import time
from bisect import bisect_right
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import imageio.v2 as iio2
import imageio.v3 as iio3
import numpy as np
from PIL import Image, ImageDraw, ImageFont

from mhrc.core.logs import get_logger
from mhrc.core.protocol import ActionResult, EpisodeStarted, ObjectPose, RobotPose, ScenarioEvent, Snapshot
from mhrc.core.records import read_records
from mhrc.core.team import PAPER_TEAM, from_kinds
from mhrc.viewer.events import caption as event_caption
from mhrc.viewer.events import captions_by_snapshot, scenario_label
from mhrc.viewer.page import distinct
from mhrc.world.quiet import pybullet as p  # no C banner on stdout
from mhrc.world.render import VIEWS, check_drawable, render
from mhrc.world.scenario import NewTarget, Scenario
from mhrc.world.sim import Sim

log = get_logger("mhrc.viewer.video")

SUFFIXES = (".mp4", ".gif")
OVERVIEW = "overview"  # the whole house from the south, fitted to the layout's bounds
FPS = 8.0
FRAMES_PER_STEP = 4  # at 8 fps: half a second per step

BACKGROUND = (24, 24, 28)
TEXT = (235, 235, 235)
DIM = (140, 140, 150)
OK = (110, 210, 120)
FAILED = (240, 110, 100)
EVENT = (250, 215, 90)  # a scenario event's caption
BAR = 3  # height of the progress bar under the captions
ROBOT_COLORS = {"alice": (200, 140, 230), "bob": (240, 190, 90), "david": (120, 170, 250)}
# the other robots of a team, in order (page.distinct): light enough to read on the dark caption band
PALETTE = [
    (250, 150, 120),
    (150, 220, 150),
    (240, 140, 190),
    (120, 220, 220),
    (220, 220, 120),
    (190, 190, 190),
    (170, 160, 250),
    (250, 200, 160),
]

Progress = Callable[[int, int], None]


class VideoError(ValueError):
    """A video cannot be made from these inputs; the message says why and what to do."""


class UnsupportedVideoFormat(VideoError):
    """The output's suffix names no format this module writes."""


class TraceWithoutSnapshots(VideoError):
    """The trace was recorded before the world published `snapshot` events."""


@dataclass(frozen=True)
class VideoInfo:
    path: Path
    frames: int
    steps: int  # snapshots rendered (the start and one per executed batch)
    width: int
    height: int
    fps: float
    seconds: float  # wall seconds for the whole job: scene build, rendering, encoding
    render_seconds: float  # of which rendering and captioning frames
    bytes: int

    @property
    def duration(self) -> float:
        """Playing time of the video in seconds."""
        return self.frames / self.fps


@dataclass(frozen=True)
class Caption:
    robot: str
    text: str
    succeeded: bool | None  # None: no action of this robot in the batch


@dataclass(frozen=True)
class Step:
    snapshot: Snapshot
    captions: list[Caption]
    sim_time: float | None  # the latest `ended` among the batch's results: the world clock after it
    events: tuple[str, ...] = ()  # the scenario events this snapshot shows, captioned ("tick 6: someone moved ...")
    added: tuple[tuple[str, str], ...] = ()  # (object, furniture) of each new target first in this snapshot


# --------------------------------------------------------------------------- reading the trace


def read_episode(trace: Path) -> tuple[EpisodeStarted, list[Step], str | None]:
    """The episode's start event, its snapshots (each with its robots' actions and outcomes), and
    for a dynamic episode its scenario as the title names it (`busy_house (d45b5975)`; None when static)."""
    started: EpisodeStarted | None = None
    scenario: str | None = None
    snapshots: list[Snapshot] = []
    results: dict[str, ActionResult] = {}
    positions: list[tuple[int, int]] = []  # each snapshot's (line, tick)
    events: list[tuple[int, int, str]] = []  # each scenario event's (line, tick, caption)
    added: list[tuple[int, str, str]] = []  # each new target's (line, object, furniture)
    for n, line in enumerate(read_records(trace)):
        msg = line.msg
        if line.problem is not None and line.named in ("episode_started", "snapshot", "scenario_event"):
            raise VideoError(f"{trace}: a {line.named} event does not match this version of mhrc ({line.problem})")
        if isinstance(msg, EpisodeStarted) and started is None:
            started = msg
        elif isinstance(msg, Snapshot):
            snapshots.append(msg)
            positions.append((n, msg.tick))
        elif isinstance(msg, ScenarioEvent):
            scenario = scenario or scenario_label(msg.scenario, msg.sha256)
            skipped = (
                f" (skipped: {msg.skipped})" if not msg.applied and msg.skipped and msg.skipped not in msg.text else ""
            )
            events.append((n, msg.tick, event_caption(msg.tick, msg.text) + skipped))
            if msg.applied and msg.event == "new_target" and msg.changed.get("object") and msg.changed.get("on"):
                added.append((n, msg.changed["object"], msg.changed["on"]))
        elif isinstance(msg, ActionResult):
            results[msg.goal_id] = msg
    if started is None:
        raise VideoError(f"{trace}: no episode_started event; is it an mhrc trace (runs/<run>/trace.jsonl)?")
    if not snapshots:
        raise TraceWithoutSnapshots(
            f"{trace}: the trace has no snapshot events: it predates snapshots (world poses after every step); "
            f"record the episode again with this version of mhrc"
        )
    robots = list(started.robots)
    steps = []
    shown = captions_by_snapshot(events, positions)
    first = [bisect_right([line for line, _ in positions], line) for line, _, _ in added]
    for k, (snap, said) in enumerate(zip(snapshots, shown)):
        done = [results[g] for g in snap.goals if g in results]
        by_robot = {r.robot: r for r in done}
        captions = [_caption(robot, by_robot.get(robot)) for robot in robots]
        ended = [r.ended for r in done if r.ended is not None]
        new = tuple((obj, on) for (_, obj, on), at in zip(added, first) if at == k)
        steps.append(Step(snap, captions, max(ended) if ended else None, tuple(said), new))
    return started, steps, scenario


def _spawns(steps: list[Step]) -> Scenario | None:
    """The episode's new targets as a scenario for the video's own Sim, which the trace's episode
    data alone builds without them: each fires (`Sim.fire_events(i)`) at the step index `i` of its
    first snapshot, so it exists from there on and the snapshots place it."""
    events = [NewTarget(tick=i, object=obj, on=on) for i, s in enumerate(steps) if i > 0 for obj, on in s.added]
    return Scenario(name="trace", sha256="", events=list(events)) if events else None


def _caption(robot: str, result: ActionResult | None) -> Caption:
    if result is None:
        return Caption(robot, "-", None)
    ok = result.outcome.succeeded
    feedback = " ".join(result.outcome.feedback.split())
    return Caption(robot, f"{result.action.call()} -> {'ok' if ok else 'FAILED'}: {feedback}", ok)


# --------------------------------------------------------------------------- poses between snapshots


def _lerp_angle(a: float, b: float, s: float) -> float:
    d = (b - a + math.pi) % (2 * math.pi) - math.pi
    return a + s * d


def _between(a: Snapshot, b: Snapshot, s: float) -> tuple[dict[str, RobotPose], dict[str, ObjectPose], dict[str, bool]]:
    """Poses a fraction `s` (0 < s <= 1) of the way from snapshot `a` to `b`; `b` itself at 1.

    Bases glide; an object held by the same robot at both ends stays in its holder's tool, any
    other object glides from where it was to where it ends up; containers change at the end."""
    if s >= 1.0:
        return b.robots, b.objects, b.open
    robots = {}
    for name, rb in b.robots.items():
        ra = a.robots.get(name, rb)
        robots[name] = RobotPose(
            x=ra.x + s * (rb.x - ra.x),
            y=ra.y + s * (rb.y - ra.y),
            yaw=_lerp_angle(ra.yaw, rb.yaw, s),
            holding=ra.holding if ra.holding == rb.holding else None,
        )
    objects = {}
    for name, ob in b.objects.items():
        oa = a.objects.get(name, ob)
        if oa.held_by is not None and oa.held_by == ob.held_by:
            objects[name] = ob
        else:
            objects[name] = ObjectPose(
                x=oa.x + s * (ob.x - oa.x),
                y=oa.y + s * (ob.y - oa.y),
                z=oa.z + s * (ob.z - oa.z),
                on=oa.on,
                inside=oa.inside and ob.inside,
                held_by=None,
            )
    return robots, objects, a.open


def _poses(
    steps: list[Step], frames_per_step: int
) -> Iterator[tuple[int, tuple[dict[str, RobotPose], dict[str, ObjectPose], dict[str, bool]]]]:
    """(step index, poses) for every frame, in order."""
    first = steps[0].snapshot
    for _ in range(frames_per_step):
        yield 0, (first.robots, first.objects, first.open)
    for i in range(1, len(steps)):
        a, b = steps[i - 1].snapshot, steps[i].snapshot
        for k in range(1, frames_per_step + 1):
            yield i, _between(a, b, k / frames_per_step)


# --------------------------------------------------------------------------- pictures


def camera(sim: Sim, view: str, width: int, height: int) -> np.ndarray:
    """An RGB picture of the scene (TinyRenderer): `overview`, or one of world/render.py's views (also
    the environment's rgb_array frame, mhrc.env)."""
    check_drawable(sim)
    if view != OVERVIEW:
        return render(sim, view, width, height)
    x0, x1, y0, y1 = sim.layout.bounds
    target = ((x0 + x1) / 2, (y0 + y1) / 2 + 0.25, 0.0)
    fov = 50.0
    # far enough that the house's width (and depth, foreshortened) fits the frame
    half = max((x1 - x0) / 2 / (width / height), (y1 - y0) / 2) + 0.9
    distance = half / math.tan(math.radians(fov / 2))
    vm = p.computeViewMatrixFromYawPitchRoll(target, distance, 0.0, -62.0, 0.0, 2, physicsClientId=sim.cid)
    pm = p.computeProjectionMatrixFOV(fov, width / height, 0.1, 50.0, physicsClientId=sim.cid)
    _, _, px, _, _ = p.getCameraImage(width, height, vm, pm, renderer=p.ER_TINY_RENDERER, physicsClientId=sim.cid)
    return np.reshape(np.asarray(px, dtype=np.uint8), (height, width, 4))[:, :, :3]


class _Captioner:
    """Draws the caption band under the picture: a header line, one line per robot, and for a
    dynamic episode (`events`) a line for the scenario events the step shows."""

    def __init__(
        self,
        width: int,
        height: int,
        started: EpisodeStarted,
        n_steps: int,
        *,
        events: bool = False,
        scenario: str | None = None,
    ) -> None:
        self.size = max(9, round(min(width / 48, height / 30)))
        self.font = ImageFont.load_default(size=self.size)
        self.line = self.size + max(2, self.size // 4)
        self.events = events
        self.band = self.line * (1 + len(started.robots) + int(events)) + self.line // 2 + BAR
        if self.band > height // 2:
            raise VideoError(
                f"a {width}x{height} frame leaves no room for the picture above the captions; make it larger"
            )
        self.width, self.height = width, height
        self.title = f"{started.scene} / {started.task} / seed {started.seed} / {started.n_objects} objects / {started.scheduler}"
        if scenario:
            self.title += f" / scenario {scenario}"
        self.n_steps = n_steps
        self.colors = distinct(list(started.robots), ROBOT_COLORS, PALETTE)

    def compose(self, picture: np.ndarray, index: int, step: Step, done: float) -> np.ndarray:
        """The frame: `picture` above, captions of step `index` below, a bar `done` (0..1) long at the bottom."""
        img = Image.new("RGB", (self.width, self.height), BACKGROUND)
        img.paste(Image.fromarray(picture), (0, 0))
        draw = ImageDraw.Draw(img)
        draw.rectangle((0, self.height - BAR, round(self.width * done) - 1, self.height - 1), fill=DIM)
        pad = max(4, self.size // 2)
        y = self.height - self.band + self.line // 4
        when = "start" if index == 0 else f"step {index}/{self.n_steps - 1}, tick {step.snapshot.tick}"
        if step.sim_time is not None:
            when += f", t = {step.sim_time:.1f} s"
        draw.text((pad, y), self._fit(f"{self.title}   {when}", self.width - 2 * pad), font=self.font, fill=TEXT)
        name_w = max(self.font.getlength(f"{c.robot}:") for c in step.captions) + pad
        for c in step.captions:
            y += self.line
            draw.text((pad, y), f"{c.robot}:", font=self.font, fill=self.colors.get(c.robot, TEXT))
            colour = DIM if c.succeeded is None else OK if c.succeeded else FAILED
            draw.text((pad + name_w, y), self._fit(c.text, self.width - 2 * pad - name_w), font=self.font, fill=colour)
        if self.events and step.events:
            draw.text(
                (pad, y + self.line),
                self._fit("; ".join(step.events), self.width - 2 * pad),
                font=self.font,
                fill=EVENT,
            )
        return np.asarray(img)

    def _fit(self, text: str, room: float) -> str:
        if self.font.getlength(text) <= room:
            return text
        while text and self.font.getlength(text + "...") > room:
            text = text[:-1]
        return text + "..."


# --------------------------------------------------------------------------- writing


class _Writer:
    """Frames to an .mp4 (imageio's ffmpeg plugin, streamed) or a .gif (Pillow)."""

    def __init__(self, out: Path, fps: float) -> None:
        self.out, self.fps = out, fps
        self.suffix = out.suffix.lower()
        self._mp4: Any = None
        self._gif: list[np.ndarray] = []
        if self.suffix == ".mp4":
            self._mp4 = iio2.get_writer(
                out,
                format="FFMPEG",
                mode="I",
                fps=fps,
                codec="libx264",
                pixelformat="yuv420p",
                quality=6,
                macro_block_size=2,
            )

    def append(self, frame: np.ndarray) -> None:
        if self._mp4 is not None:
            self._mp4.append_data(frame)
        else:
            self._gif.append(frame)

    def close(self) -> None:
        if self._mp4 is not None:
            self._mp4.close()
        elif self._gif:
            iio3.imwrite(
                self.out,
                np.stack(self._gif),
                plugin="pillow",
                extension=".gif",
                duration=round(1000 / self.fps),
                loop=0,
            )


def render_video(
    trace: Path,
    out: Path,
    *,
    width: int = 640,
    height: int = 480,
    frames_per_step: int = FRAMES_PER_STEP,
    fps: float = FPS,
    view: str = OVERVIEW,
    progress: Progress | None = None,
) -> VideoInfo:
    """Render the episode recorded in `trace` to `out` (.mp4 or .gif, by suffix).

    Raises UnsupportedVideoFormat for another suffix, TraceWithoutSnapshots for a trace older
    than snapshot events, VideoError for other unusable inputs. `progress(done, total)` is
    called after every frame."""
    t0 = time.perf_counter()
    trace, out = Path(trace), Path(out)
    if out.suffix.lower() not in SUFFIXES:
        raise UnsupportedVideoFormat(
            f"{out}: cannot write a {out.suffix or 'suffix-less'} video; use one of {', '.join(SUFFIXES)}"
        )
    if view != OVERVIEW and view not in VIEWS:
        raise VideoError(f"unknown view {view!r}; use one of {', '.join([OVERVIEW, *VIEWS])}")
    if frames_per_step < 1 or fps <= 0:
        raise VideoError(f"frames_per_step must be at least 1 and fps positive (got {frames_per_step}, {fps})")
    if width < 64 or height < 64 or (out.suffix.lower() == ".mp4" and (width % 2 or height % 2)):
        raise VideoError(f"width and height must be at least 64 (and even, for .mp4); got {width}x{height}")
    started, steps, scenario = read_episode(trace)
    captioner = _Captioner(width, height, started, len(steps), events=any(s.events for s in steps), scenario=scenario)
    total = len(steps) * frames_per_step
    out.parent.mkdir(parents=True, exist_ok=True)
    rendering = 0.0
    with Sim(
        visuals=True,
        task=started.task,
        scene=started.scene,
        seed=started.seed,
        n_objects=started.n_objects,
        team=PAPER_TEAM if started.team is None else from_kinds(started.team.name, started.team.kinds),
        robots=tuple(started.robots),
        aids=tuple(started.aids),
        scenario=_spawns(steps),
    ) as sim:
        writer = _Writer(out, fps)
        try:
            for n, (i, (robots, objects, opened)) in enumerate(_poses(steps, frames_per_step), start=1):
                t = time.perf_counter()
                sim.fire_events(i)  # a new target joins from its first snapshot on (_spawns)
                sim.apply_snapshot(robots, objects, opened)
                frame = captioner.compose(camera(sim, view, width, height - captioner.band), i, steps[i], n / total)
                rendering += time.perf_counter() - t
                writer.append(frame)
                if progress is not None:
                    progress(n, total)
        finally:
            writer.close()
    info = VideoInfo(
        out, total, len(steps), width, height, fps, time.perf_counter() - t0, rendering, out.stat().st_size
    )
    log.info(
        "video written",
        path=str(out),
        frames=info.frames,
        steps=info.steps,
        seconds=round(info.seconds, 2),
        bytes=info.bytes,
    )
    return info
