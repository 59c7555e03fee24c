"""The viewer's data, assembled from a trace: header, robots' steps, map frames, messages.

Steps are keyed by goal id: a request, its ack, its result; each robot's thoughts are paired with
its requests in order (an agent publishes its thought, then its request). Map frames are the
world's `snapshot` events; a trace without them (protocol version 1) gets frames from the
robots' own observations in their results, with no objects. The task's targets and their ends
come from mhrc.viewer.targets; each navigate's planned route from its outcome's `path`; a dynamic
episode's scenario events, with their frame and place, from mhrc.viewer.events.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mhrc.core.protocol import (
    Action,
    ActionAck,
    ActionRequest,
    ActionResult,
    EpisodeDone,
    EpisodeStarted,
    Metrics,
    RobotMessage,
    RobotPose,
    Snapshot,
    Thought,
)
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.viewer.events import ScenarioMark, scenario_marks, scenario_name
from mhrc.viewer.frames import Frame
from mhrc.viewer.load import LoadedTrace
from mhrc.viewer.scene_map import SceneMap, scene_map
from mhrc.viewer.targets import TaskView, task_view
from mhrc.world.kinds import KINDS, flight_altitude


@dataclass
class Step:
    """One action of one robot: what it thought, asked, was told, and what happened."""

    robot: str
    goal_id: str
    tick: int | None = None
    action: Action | None = None
    call: str = ""
    ack: ActionAck | None = None
    result: ActionResult | None = None
    thought: Thought | None = None
    frame: int | None = None  # index of the map frame right after it executed


@dataclass
class MapMessage:
    sender: str
    to: str
    content: str
    sent: int  # the tick it was sent at
    delivered: int | None  # the receiver's observation tick that carried it, if seen
    frame: int | None = None


@dataclass
class Header:
    """What the report's header says of the episode: its start event's facts, its end, its metrics."""

    run: str | None
    task: str | None
    scene: str | None
    seed: int | None
    n_objects: int | None
    robots: list[str]
    fliers: dict[str, float]  # robot -> the altitude it flies at (m)
    models: dict[str, str]  # robot -> the policy its thoughts name
    horizon: int | None
    scheduler: str | None
    fidelity: str | None
    aids: list[str] | None
    time_scale: float | None
    step_seconds: float | None
    lower_bound: int | None
    reason: str | None
    scenario: tuple[str, str] | None  # (name, sha256), or None for a static episode
    metrics: Metrics | None
    versions: list[int]
    trace: str
    protocol: str = DEFAULT_PROTOCOL  # how the team decided (mhrc.agents.protocols): the paper's unless the trace says


@dataclass
class EpisodeView:
    header: Header
    robots: list[str]
    steps: dict[str, list[Step]]
    frames: list[Frame]
    frames_from: str  # "snapshots", "observations" or "none"
    messages: list[MapMessage]
    scene: SceneMap | None
    task: TaskView | None = None
    routes: dict[str, list[list[float]]] = field(default_factory=dict)  # goal id -> a navigate's planned route
    events: list[ScenarioMark] = field(default_factory=list)  # a dynamic episode's scenario events (mhrc.viewer.events)
    warnings: list[str] = field(default_factory=list)


def fliers(started: EpisodeStarted | None, scene: SceneMap | None) -> dict[str, float]:
    """The robots of the recorded team that fly, and the altitude they fly at in that house (m),
    as the world set it (world/kinds.py flight_altitude)."""
    kinds = started.team.kinds if started is not None and started.team is not None else {}
    out = {}
    for robot, kind in kinds.items():
        spec = KINDS.get(kind)
        if spec is not None and spec.flies:
            out[robot] = flight_altitude(spec, scene.tallest if scene else 0.0)
    return out


def _deliver(messages: list[MapMessage], result: ActionResult) -> None:
    """Mark the messages a result's observation carried as delivered at its tick (the first not yet delivered of each)."""
    obs = result.observation
    for m in obs.new_messages:
        for mm in messages:
            if mm.delivered is None and mm.sender == m.sender and mm.to == m.to and mm.content == m.content:
                mm.delivered = obs.tick
                break


def build_view(trace: LoadedTrace) -> EpisodeView:
    warnings = list(trace.warnings)
    started = trace.first(EpisodeStarted)
    done = trace.last(EpisodeDone)

    steps: dict[str, dict[str, Step]] = {}
    thoughts: dict[str, list[Thought]] = {}
    order: dict[str, list[str]] = {}
    messages: list[MapMessage] = []
    robots: list[str] = list(started.robots) if started is not None else []
    policies: dict[str, str] = {}

    def step(robot: str, goal: str) -> Step:
        if robot not in steps:
            steps[robot] = {}
            order[robot] = []
            if robot not in robots:
                robots.append(robot)
        if goal not in steps[robot]:
            steps[robot][goal] = Step(robot=robot, goal_id=goal)
            order[robot].append(goal)
        return steps[robot][goal]

    for line in trace.records:
        msg = line.msg
        if isinstance(msg, Thought):
            thoughts.setdefault(msg.robot, []).append(msg)
            if msg.policy:
                policies.setdefault(msg.robot, msg.policy)
        elif isinstance(msg, ActionRequest):
            s = step(msg.robot, msg.goal_id)
            s.tick = msg.tick
            s.action = msg.action
        elif isinstance(msg, ActionAck):
            step(msg.robot, msg.goal_id).ack = msg
        elif isinstance(msg, ActionResult):
            s = step(msg.robot, msg.goal_id)
            s.result = msg
            s.action = s.action or msg.action
            if s.tick is None:
                s.tick = msg.tick
            _deliver(messages, msg)
        elif isinstance(msg, RobotMessage):
            messages.append(MapMessage(msg.sender, msg.to, msg.content, msg.tick, None))
    # async: a message reaches its receiver when sent
    if started is not None and started.scheduler == "async":
        for mm in messages:
            if mm.delivered is None:
                mm.delivered = mm.sent

    # pair thoughts with requests, in order, per robot
    out: dict[str, list[Step]] = {}
    for robot in robots:
        lane = [steps.get(robot, {})[g] for g in order.get(robot, [])]
        th = list(thoughts.get(robot, []))
        for s in lane:
            if s.action is None:
                continue
            # the next thought of this robot at or before the step's tick
            for i, t in enumerate(th):
                if s.tick is None or t.tick <= s.tick:
                    s.thought = th.pop(i)
                    break
        for s in lane:
            s.call = s.action.call() if s.action is not None else ""
        out[robot] = lane

    frames, frames_from = _frames(trace, out)
    goal_frame = {g: i for i, f in enumerate(frames) for g in f.goals}
    for lane in out.values():
        for s in lane:
            s.frame = goal_frame.get(s.goal_id)
    for mm in messages:
        mm.frame = next((i for i, f in enumerate(frames) if f.tick >= mm.sent and i > 0), None)

    fixtures: dict[str, tuple[float, float]] = {}
    scene_names: set[str] = set()
    for r in trace.messages(ActionResult):
        for f in r.observation.furniture:
            if not f.stand_poses:
                fixtures[f.name] = (f.position[0], f.position[1])
            else:
                scene_names.add(f.name)
    scene = (
        scene_map(started.scene, {k: v for k, v in fixtures.items() if k not in scene_names}, warnings)
        if started is not None and started.scene
        else None
    )

    marks = scenario_marks(trace, frames, frames_from, scene)
    metrics = done.metrics if done is not None else None
    header = Header(
        run=started.run if started else None,
        task=started.task if started else None,
        scene=started.scene if started else None,
        seed=started.seed if started else None,
        n_objects=started.n_objects if started else None,
        robots=robots,
        fliers=fliers(started, scene),
        models={r: policies.get(r, "unknown") for r in robots},
        horizon=started.horizon if started else None,
        scheduler=started.scheduler if started else None,
        fidelity=started.fidelity if started else None,
        aids=started.aids if started else None,
        time_scale=started.time_scale if started else None,
        step_seconds=started.step_seconds if started else None,
        lower_bound=_lower_bound(started, metrics),
        reason=done.reason if done else None,
        scenario=scenario_name(marks),
        metrics=metrics,
        versions=sorted(trace.versions),
        trace=str(trace.path),
        protocol=started.protocol if started else DEFAULT_PROTOCOL,
    )
    return EpisodeView(
        header=header,
        robots=robots,
        steps=out,
        frames=frames,
        frames_from=frames_from,
        messages=messages,
        scene=scene,
        task=task_view(trace, started, frames, frames_from, metrics),
        routes=_routes(out),
        events=marks,
        warnings=warnings,
    )


def _lower_bound(started: EpisodeStarted | None, metrics: Metrics | None) -> int | None:
    """The episode's TS lower bound: its start event's, else its metrics' (mhrc.world.bound)."""
    if started is not None and started.lower_bound is not None:
        return started.lower_bound
    return metrics.lower_bound if metrics is not None else None


def _routes(lanes: dict[str, list[Step]]) -> dict[str, list[list[float]]]:
    """The planned route of every navigate whose outcome carries one (traces before routes have none:
    the map joins the stops with straight lines)."""
    out: dict[str, list[list[float]]] = {}
    for lane in lanes.values():
        for s in lane:
            path = s.result.outcome.path if s.result is not None else None
            if path is not None and len(path) >= 2:
                out[s.goal_id] = [[x, y] for x, y in path]
    return out


def _frames(trace: LoadedTrace, lanes: dict[str, list[Step]]) -> tuple[list[Frame], str]:
    snaps = trace.messages(Snapshot)
    if snaps:
        return [Frame(s.tick, list(s.goals), dict(s.robots), dict(s.objects), dict(s.open)) for s in snaps], "snapshots"
    # no snapshots: each robot's base from its own observations, after each tick
    by_tick: dict[int, list[tuple[Step, ActionResult]]] = {}
    for s in (s for lane in lanes.values() for s in lane):
        if s.result is not None:
            by_tick.setdefault(s.result.tick, []).append((s, s.result))
    if not by_tick:
        return [], "none"
    frames: list[Frame] = []
    pose: dict[str, RobotPose] = {}
    for tick in sorted(by_tick):
        goals = []
        for s, result in by_tick[tick]:
            status = result.observation.status
            if status.base is not None:
                pose[s.robot] = RobotPose(x=status.base.x, y=status.base.y, yaw=status.base.yaw, holding=status.holding)
            elif status.arm_base is not None:
                pose[s.robot] = RobotPose(x=status.arm_base[0], y=status.arm_base[1], yaw=0.0, holding=status.holding)
            goals.append(s.goal_id)
        frames.append(Frame(tick, goals, dict(pose)))
    return frames, "observations"
