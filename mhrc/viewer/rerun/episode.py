"""An episode's trace records, one at a time, as a Rerun recording.

`EpisodeLogger.feed` takes the records (mhrc.core.records.TraceLine) in the order a trace holds them
or the bus delivers them, so a trace read back (`mhrc show --rerun`) and an episode seen live
(`mhrc up --rerun`, mhrc.viewer.rerun.live) make the same recording. Every record is logged on two
timelines: `tick` (the world's tick: a snapshot or a tick's progress taken after tick t executed is
at t + 1, as the robots observe it) and `sim_time` (simulated seconds, the newest action's end seen).

The entity tree (docs/seeing.md, "In Rerun"):

    world/walls, world/furniture/<name>, world/furniture/<name>/state, world/goal_area   the house
    world/robots/<robot> (its pose), world/robots/<robot>/body                         each robot
    world/paths/<robot>, world/routes/<robot>                   where it went, a navigate's planned route
    world/objects, world/beliefs/<robot>              objects where the world has them / where a robot believes
    agents/<robot>/thought, /action, /outcome, /inbox                    each robot's text logs
    agents/<robot>/coordination          its leader and job, where a protocol other than the paper's set them
    messages, events                                     messages between robots; the episode's events
    progress/placed, progress/ps                               placed objects and partial success
"""

from __future__ import annotations

from dataclasses import dataclass, field

import rerun as rr

from mhrc.core import protocol as wire
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.core.records import LineKind, TraceLine
from mhrc.core.team import PAPER_TEAM
from mhrc.viewer.rerun.blueprint import blueprint
from mhrc.viewer.rerun.house import Body, body_of, log_body, log_house, log_open
from mhrc.world.layouts import Layout, get_layout

OBJECT_COLOR = (230, 60, 60, 255)
BELIEF_COLOR = (60, 140, 230, 200)
PATH_COLOR = (120, 120, 220, 255)
ROUTE_COLOR = (250, 150, 40, 255)
INFO, WARN = rr.TextLogLevel.INFO, rr.TextLogLevel.WARN


@dataclass
class _Robot:
    kind: str
    body: Body
    path: list[tuple[float, float, float]] = field(default_factory=list)


class EpisodeLogger:
    """Logs trace records into `rec` (a RecordingStream with its sink set); `warnings` collects what could
    not be drawn. Not thread-safe: one thread feeds it (live: the logging thread)."""

    def __init__(self, rec: rr.RecordingStream) -> None:
        self.rec = rec
        self.warnings: list[str] = []
        self.records = 0  # records fed
        self._layout: Layout | None = None
        self._kinds: dict[str, str] = {}  # robot -> kind, from episode_started's team (the paper's before teams)
        self._robots: dict[str, _Robot] = {}
        self._shown: tuple[str, ...] = ()  # the robots the blueprint last sent has panels for
        self._open: dict[str, bool] = {}
        self._coordination: dict[str, wire.Coordination] = {}  # robot -> what its protocol last decided for it
        self._ticks: dict[str, int] = {}  # goal id -> its request's tick
        self._tick = 0
        self._sim = 0.0
        self._snapshots = 0

    # ------------------------------------------------------------------ the records

    def feed(self, line: TraceLine) -> None:
        """Log one record (a line that is no `put`, or whose message did not decode, is passed over)."""
        self.records += 1
        if line.kind is not LineKind.PUT or line.msg is None:
            return
        msg = line.msg
        if isinstance(msg, wire.EpisodeStarted):
            self._started(msg)
        elif isinstance(msg, wire.Snapshot):
            self._snapshot(msg)
        elif isinstance(msg, wire.Thought):
            self._thought(msg)
        elif isinstance(msg, wire.ActionRequest):
            self._ticks[msg.goal_id] = msg.tick
            self._at(msg.tick)
            self._text(msg.robot, "action", f"{msg.action.call()}  [goal {msg.goal_id}]")
        elif isinstance(msg, wire.ActionAck):
            if not msg.accepted:
                self._at(self._ticks.get(msg.goal_id, self._tick))
                code = msg.code.value if msg.code is not None else "rejected"
                self._text(msg.robot, "action", f"rejected ({code}): {msg.reason}", WARN)
        elif isinstance(msg, wire.ActionResult):
            self._result(msg)
        elif isinstance(msg, wire.RobotMessage):
            self._at(msg.tick)
            self.rec.log("messages", rr.TextLog(f"{msg.sender} -> {msg.to}: {msg.content}", level=INFO))
            self._text(msg.to, "inbox", f"from {msg.sender}: {msg.content}")
        elif isinstance(msg, wire.TickClosed):
            self._at(msg.tick + 1)
            self._progress(msg.placed, msg.total)
        elif isinstance(msg, wire.ScenarioEvent):
            self._at(msg.tick)
            level = INFO if msg.applied else WARN
            text = msg.text or f"{msg.event} ({'applied' if msg.applied else 'skipped: ' + str(msg.skipped)})"
            self.rec.log("events", rr.TextLog(f"scenario {msg.scenario} #{msg.index}: {text}", level=level))
        elif isinstance(msg, wire.RobotAttached):
            self._robot(msg.robot)
            self._at(msg.tick)
            self.rec.log("events", rr.TextLog(f"{msg.robot} attached ({msg.agent_id})", level=INFO))
        elif isinstance(msg, wire.RobotDetached):
            self._at(msg.tick)
            self.rec.log("events", rr.TextLog(f"{msg.robot} detached: {msg.reason}", level=WARN))
        elif isinstance(msg, wire.EpisodeDone):
            self._done(msg)

    def finish(self) -> None:
        """The blueprint for every robot seen (a trace without episode_started names its robots as they act)."""
        self._send_blueprint()

    # ------------------------------------------------------------------ time

    def _at(self, tick: int, sim: float | None = None) -> None:
        self._tick = tick
        if sim is not None:
            self._sim = max(self._sim, sim)
        self.rec.set_time("tick", sequence=tick)
        self.rec.set_time("sim_time", duration=self._sim)

    # ------------------------------------------------------------------ handlers

    def _started(self, msg: wire.EpisodeStarted) -> None:
        self._at(0)
        kinds = msg.team.kinds if msg.team is not None else PAPER_TEAM.kinds
        self._kinds.update(kinds)
        try:
            self._layout = get_layout(msg.scene)
        except Exception as exc:  # an unknown name or a layout file that is gone: the robots without the house
            self.warnings.append(f"scene {msg.scene!r} could not be loaded ({exc}): the house is not drawn")
        if self._layout is not None:
            log_house(self.rec, self._layout)
        for robot in self._robots:  # attached before the start said its kind: drawn again as what it is
            self._robots[robot] = _Robot(
                self._kinds.get(robot, "?"), body_of(self._kinds.get(robot, "?"), self._layout)
            )
            log_body(self.rec, robot, self._robots[robot].body)
        for robot in msg.robots:
            self._robot(robot)
        self.rec.log(
            "events",
            rr.TextLog(
                f"episode {msg.run}: {msg.task} in {msg.scene}, seed {msg.seed}, {msg.n_objects} objects, "
                f"robots {', '.join(msg.robots)}, {msg.scheduler}, horizon {msg.horizon}"
                + (f", protocol {msg.protocol}" if msg.protocol != DEFAULT_PROTOCOL else ""),
                level=INFO,
            ),
        )
        self._send_blueprint()

    def _robot(self, robot: str) -> _Robot:
        known = self._robots.get(robot)
        if known is None:
            known = self._robots[robot] = _Robot(
                self._kinds.get(robot, "?"), body_of(self._kinds.get(robot, "?"), self._layout)
            )
            log_body(self.rec, robot, known.body)
        return known

    def _pose(self, robot: str, x: float, y: float, yaw: float) -> None:
        r = self._robot(robot)
        where = (x, y, r.body.z)
        self.rec.log(
            f"world/robots/{robot}",
            rr.Transform3D(translation=where, rotation=rr.RotationAxisAngle(axis=(0.0, 0.0, 1.0), radians=yaw)),
        )
        if not r.path or r.path[-1] != where:
            r.path.append(where)
            if len(r.path) > 1:
                self.rec.log(f"world/paths/{robot}", rr.LineStrips3D([r.path], colors=[PATH_COLOR], labels=[robot]))

    def _snapshot(self, msg: wire.Snapshot) -> None:
        self._snapshots += 1
        self._at(msg.tick + 1 if msg.goals else msg.tick)
        for robot, pose in msg.robots.items():
            self._pose(robot, pose.x, pose.y, pose.yaw)
        names = sorted(msg.objects)
        if names:
            self.rec.log(
                "world/objects",
                rr.Points3D(
                    [(msg.objects[n].x, msg.objects[n].y, msg.objects[n].z) for n in names],
                    labels=names,
                    colors=[OBJECT_COLOR] * len(names),
                    radii=0.05,
                ),
            )
        for name, is_open in msg.open.items():
            if self._open.get(name) != is_open and self._layout is not None:
                log_open(self.rec, self._layout, name, is_open)
            self._open[name] = is_open

    def _thought(self, msg: wire.Thought) -> None:
        self._robot(msg.robot)
        self._at(msg.tick)
        if msg.reply:  # a model's reply, its reasoning before it when the server sent one apart
            text = (f"{msg.reasoning}\n---\n" if msg.reasoning else "") + msg.reply
        else:  # a heuristic's (or a replayed) decision
            text = f"{msg.policy}: {msg.action or msg.reasoning or '(no action)'}"
        if msg.parse_error:
            text += f"\n(no action: {msg.parse_error})"
        self._text(msg.robot, "thought", text, WARN if msg.parse_error else INFO)
        c = msg.coordination
        if c is not None and self._coordination.get(msg.robot) != c:  # a new leader or a new job: who leads, what whom
            self._coordination[msg.robot] = c
            job = f"job {c.job}" + (f" from {c.by}" if c.by else "") if c.job else "no job"
            self._text(msg.robot, "coordination", job + (f"; leader {c.leader}" if c.leader else ""))

    def _result(self, msg: wire.ActionResult) -> None:
        self._at(msg.tick, msg.ended)
        out = msg.outcome
        status = "ok" if out.succeeded else f"failed ({out.code.value})"
        self._text(
            msg.robot,
            "outcome",
            f"{msg.action.call()}: {status}, {out.sim_time:.1f} s: {out.feedback}",
            INFO if out.succeeded else WARN,
        )
        if out.path and len(out.path) >= 2:
            z = self._robot(msg.robot).body.z
            self.rec.log(
                f"world/routes/{msg.robot}",
                rr.LineStrips3D([[(x, y, z) for x, y in out.path]], colors=[ROUTE_COLOR], labels=[msg.robot]),
            )
        obs = msg.observation
        self._at(obs.tick)
        believed = [o for o in obs.objects if o.held_by is None]
        self.rec.log(
            f"world/beliefs/{msg.robot}",
            rr.Points3D(
                [o.position for o in believed],
                labels=[f"{o.name}?" for o in believed],
                colors=[BELIEF_COLOR] * len(believed),
                radii=0.03,
            ),
        )
        if self._snapshots == 0:  # a trace of protocol version 1: the poses from the robots' own observations
            body = obs.status
            if body.base is not None:
                self._pose(msg.robot, body.base.x, body.base.y, body.base.yaw)
            elif body.arm_base is not None:
                self._pose(msg.robot, body.arm_base[0], body.arm_base[1], 0.0)

    def _done(self, msg: wire.EpisodeDone) -> None:
        m = msg.metrics
        self._at(m.temporal_steps, m.sim_time or None)
        self._progress(m.placed, m.total)
        self.rec.log(
            "events",
            rr.TextLog(
                f"episode done ({msg.reason}): success {m.success}, PS {m.partial_success:.2f} "
                f"({m.placed}/{m.total} placed), TS {m.temporal_steps}, action steps {m.action_steps}",
                level=INFO if m.success else WARN,
            ),
        )

    # ------------------------------------------------------------------ helpers

    def _progress(self, placed: int, total: int) -> None:
        self.rec.log("progress/placed", rr.Scalars([float(placed)]))
        self.rec.log("progress/ps", rr.Scalars([placed / total if total else 0.0]))

    def _text(self, robot: str, what: str, text: str, level: rr.TextLogLevel = INFO) -> None:
        self.rec.log(f"agents/{robot}/{what}", rr.TextLog(text, level=level))

    def _send_blueprint(self) -> None:
        robots = tuple(self._robots)
        if robots != self._shown:
            self._shown = robots
            self.rec.send_blueprint(blueprint(robots))
