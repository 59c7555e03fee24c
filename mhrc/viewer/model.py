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
from typing import Any

from mhrc.viewer.events import ScenarioMark, scenario_marks, scenario_name
from mhrc.viewer.load import LoadedTrace
from mhrc.viewer.targets import TaskView, task_view
from mhrc.world.layouts import Layout, get_layout
from mhrc.world.robots import KINDS, flight_altitude


@dataclass
class Step:
    """One action of one robot: what it thought, asked, was told, and what happened."""

    robot: str
    goal_id: str
    tick: int | None = None
    action: dict[str, Any] | None = None
    call: str = ""
    ack: dict[str, Any] | None = None
    result: dict[str, Any] | None = None
    thought: dict[str, Any] | None = None
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
class EpisodeView:
    header: dict[str, Any]
    robots: list[str]
    steps: dict[str, list[Step]]
    frames: list[dict[str, Any]]
    frames_from: str  # "snapshots", "observations" or "none"
    messages: list[MapMessage]
    scene: dict[str, Any] | None
    task: TaskView | None = None
    routes: dict[str, list[list[float]]] = field(default_factory=dict)  # goal id -> a navigate's planned route
    events: list[ScenarioMark] = field(default_factory=list)  # a dynamic episode's scenario events (mhrc.viewer.events)
    warnings: list[str] = field(default_factory=list)


def _call(action: dict[str, Any] | None) -> str:
    if not action:
        return ""
    skill = action.get("skill", "?")
    args = [f"{v!r}" if k == "content" else str(v) for k, v in action.items() if k != "skill"]
    return f"{skill}({', '.join(args)})"


def _robot_of(key: str) -> str | None:
    parts = key.split("/")
    for marker in ("robot", "agent"):
        if marker in parts:
            i = parts.index(marker)
            if i + 1 < len(parts):
                return parts[i + 1]
    return None


def scene_map(scene: str, fixtures: dict[str, tuple[float, float]], warnings: list[str]) -> dict[str, Any] | None:
    """What the map draws of the house: bounds, walls, furniture footprints, goal area, fixtures."""
    try:
        layout: Layout = get_layout(scene)
    except Exception as exc:  # an unknown name or a layout file that is gone: draw what the snapshots show
        warnings.append(f"scene {scene!r} could not be loaded ({exc}): the house is not drawn")
        return None
    furniture = []
    for f in layout.furniture:
        item: dict[str, Any] = {
            "name": f.name,
            "kind": f.kind,
            "style": f.style,
            "x": f.center[0],
            "y": f.center[1],
            "sx": f.size[0],
            "sy": f.size[1],
            "openable": f.container is not None,
            "color": list(f.color),
        }
        opened = f.open_drawer_footprint()
        if opened is not None:
            (cx, cy), (sx, sy) = opened
            item["open_footprint"] = [cx, cy, sx, sy]
        furniture.append(item)
    return {
        "name": layout.name,
        "bounds": list(layout.bounds),
        "walls": [list(w) for w in layout.walls],
        "furniture": furniture,
        "bob_table": layout.bob_table,
        "bob_base": list(layout.bob_base[:2]),
        "goal_area": list(layout.goal_area),
        "fixtures": [{"name": n, "x": x, "y": y} for n, (x, y) in sorted(fixtures.items())],
        "tallest": max((f.size[2] for f in layout.furniture), default=0.0),
    }


def fliers(started: dict[str, Any], scene: dict[str, Any] | None) -> dict[str, float]:
    """The robots of the recorded team that fly, and the altitude they fly at in that house (m),
    as the world set it (world/robots.py flight_altitude)."""
    kinds = (started.get("team") or {}).get("kinds") or {}
    out = {}
    for robot, kind in kinds.items():
        spec = KINDS.get(kind)
        if spec is not None and spec.flies:
            out[robot] = flight_altitude(spec, scene["tallest"] if scene else 0.0)
    return out


def build_view(trace: LoadedTrace) -> EpisodeView:
    warnings = list(trace.warnings)
    started = (trace.messages("episode_started") or [{}])[0]
    done_list = trace.messages("episode_done")
    done = done_list[-1] if done_list else None

    steps: dict[str, dict[str, Step]] = {}
    thoughts: dict[str, list[dict[str, Any]]] = {}
    order: dict[str, list[str]] = {}
    messages: list[MapMessage] = []
    robots: list[str] = list(started.get("robots") or [])
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

    for row in trace.rows:
        msg = row.get("msg")
        if not isinstance(msg, dict):
            continue
        kind = msg.get("kind")
        robot = msg.get("robot") or _robot_of(row["key"])
        goal = msg.get("goal_id")
        if kind == "thought" and isinstance(robot, str):
            thoughts.setdefault(robot, []).append(msg)
            if msg.get("policy"):
                policies.setdefault(robot, str(msg["policy"]))
        elif kind == "action_request" and isinstance(robot, str) and isinstance(goal, str):
            s = step(robot, goal)
            s.tick = msg.get("tick", s.tick)
            s.action = msg.get("action")
        elif kind == "action_ack" and isinstance(robot, str) and isinstance(goal, str):
            step(robot, goal).ack = msg
        elif kind == "action_result" and isinstance(robot, str) and isinstance(goal, str):
            s = step(robot, goal)
            s.result = msg
            s.action = s.action or msg.get("action")
            if s.tick is None:
                s.tick = msg.get("tick")
            obs = msg.get("observation") or {}
            for m in obs.get("new_messages") or []:
                for mm in messages:
                    if (
                        mm.delivered is None
                        and mm.sender == m.get("sender")
                        and mm.to == m.get("to")
                        and mm.content == m.get("content")
                    ):
                        mm.delivered = obs.get("tick")
                        break
        elif kind == "message":
            messages.append(
                MapMessage(
                    str(msg.get("sender")),
                    str(msg.get("to")),
                    str(msg.get("content", "")),
                    int(msg.get("tick", 0)),
                    None,
                )
            )
    # async: a message reaches its receiver when sent
    if started.get("scheduler") == "async":
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
                if s.tick is None or t.get("tick", 0) <= s.tick:
                    s.thought = th.pop(i)
                    break
        for s in lane:
            s.call = _call(s.action)
        out[robot] = lane

    frames, frames_from = _frames(trace, out, started)
    goal_frame = {g: i for i, f in enumerate(frames) for g in f.get("goals", [])}
    for lane in out.values():
        for s in lane:
            s.frame = goal_frame.get(s.goal_id)
    for mm in messages:
        mm.frame = next((i for i, f in enumerate(frames) if f["tick"] >= mm.sent and i > 0), None)

    fixtures: dict[str, tuple[float, float]] = {}
    scene_names: set[str] = set()
    for r in trace.messages("action_result"):
        for f in (r.get("observation") or {}).get("furniture") or []:
            if not f.get("stand_poses") and isinstance(f.get("position"), list):
                fixtures[str(f.get("name"))] = (float(f["position"][0]), float(f["position"][1]))
            else:
                scene_names.add(str(f.get("name")))
    scene = (
        scene_map(str(started["scene"]), {k: v for k, v in fixtures.items() if k not in scene_names}, warnings)
        if started.get("scene")
        else None
    )

    marks = scenario_marks(trace, frames, frames_from, scene)
    metrics = (done or {}).get("metrics") or {}
    header = {
        "run": started.get("run"),
        "task": started.get("task"),
        "scene": started.get("scene"),
        "seed": started.get("seed"),
        "n_objects": started.get("n_objects"),
        "robots": robots,
        "fliers": fliers(started, scene),
        "models": {r: policies.get(r, "unknown") for r in robots},
        "horizon": started.get("horizon"),
        "scheduler": started.get("scheduler"),
        "fidelity": started.get("fidelity", "unrecorded" if started else None),
        "aids": started.get("aids"),
        "time_scale": started.get("time_scale"),
        "step_seconds": started.get("step_seconds"),
        "lower_bound": started.get("lower_bound", metrics.get("lower_bound")),
        "reason": (done or {}).get("reason"),
        "scenario": scenario_name(marks),  # (name, sha256), or None for a static episode
        "metrics": metrics,
        "versions": sorted(trace.versions),
        "trace": str(trace.path),
    }
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


def _routes(lanes: dict[str, list[Step]]) -> dict[str, list[list[float]]]:
    """The planned route of every navigate whose outcome carries one (traces before routes have none:
    the map joins the stops with straight lines)."""
    out: dict[str, list[list[float]]] = {}
    for lane in lanes.values():
        for s in lane:
            path = ((s.result or {}).get("outcome") or {}).get("path")
            if isinstance(path, list) and len(path) >= 2:
                try:
                    out[s.goal_id] = [[float(p[0]), float(p[1])] for p in path]
                except (TypeError, ValueError, IndexError):
                    continue  # a damaged route: the straight line it is
    return out


def _frames(
    trace: LoadedTrace, lanes: dict[str, list[Step]], started: dict[str, Any]
) -> tuple[list[dict[str, Any]], str]:
    snaps = trace.messages("snapshot")
    if snaps:
        return [
            {
                "tick": s.get("tick", 0),
                "goals": list(s.get("goals") or []),
                "robots": s.get("robots") or {},
                "objects": s.get("objects") or {},
                "open": s.get("open") or {},
            }
            for s in snaps
        ], "snapshots"
    # no snapshots: each robot's base from its own observations, after each tick
    results = [s for lane in lanes.values() for s in lane if s.result is not None]
    if not results:
        return [], "none"
    by_tick: dict[int, list[Step]] = {}
    for s in results:
        by_tick.setdefault(int(s.result.get("tick", 0)) if s.result else 0, []).append(s)
    frames: list[dict[str, Any]] = []
    pose: dict[str, dict[str, Any]] = {}
    for tick in sorted(by_tick):
        goals = []
        for s in by_tick[tick]:
            obs = (s.result or {}).get("observation") or {}
            status = obs.get("status") or {}
            base = status.get("base")
            arm = status.get("arm_base")
            if isinstance(base, dict):
                pose[s.robot] = {
                    "x": base.get("x", 0.0),
                    "y": base.get("y", 0.0),
                    "yaw": base.get("yaw", 0.0),
                    "holding": status.get("holding"),
                }
            elif isinstance(arm, list) and len(arm) >= 2:
                pose[s.robot] = {"x": arm[0], "y": arm[1], "yaw": 0.0, "holding": status.get("holding")}
            goals.append(s.goal_id)
        frames.append(
            {"tick": tick, "goals": goals, "robots": {k: dict(v) for k, v in pose.items()}, "objects": {}, "open": {}}
        )
    return frames, "observations"
