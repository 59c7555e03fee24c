"""Which objects the task wanted where, and where each ended: the first question about a failure.

Read from the trace, in this order of preference:

- the targets: the world's answer key in `episode_done` (`targets`, `goals`, `ordered`: said
  once the episode is over, so no agent learns from it), else Bob's
  observations (`targets`, the task's list as Bob is told it), else the task's own generator
  re-run on the episode's task, scene, seed and object count (said so on the page: a trace
  from another version of the generator may differ);
- each target's goal (the fixture it must end on): `episode_done.goals`, else Bob's
  observations' `goals` (sent only with the goal_map aid), else the task's `goal()` of the
  generated object of that name, used only when the generator's targets are the trace's;
- where every object ended: the last `snapshot` (ground truth); a trace without snapshots
  (protocol version 1) has only what the robots last saw of it.

Distractors are the objects the trace shows that are not targets. A target is placed when it
ends on its goal and nobody holds it; for an ordered task (a sandwich) the world counts only
the stack's correct prefix, so the page shows the world's count beside this one when they differ.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mhrc.core.protocol import (
    ActionResult,
    EpisodeDone,
    EpisodeStarted,
    Metrics,
    ObjectPose,
    ObjectView,
    Observation,
    Turn,
)
from mhrc.viewer.frames import Frame
from mhrc.viewer.load import LoadedTrace
from mhrc.world.layouts import get_layout
from mhrc.world.tasks import get_task


@dataclass
class ObjectFate:
    """One object: its role, its goal, where it ended and whether that is its goal."""

    name: str
    role: str  # "target", "distractor"
    goal: str | None = None
    where: str = "unknown"
    x: float | None = None
    y: float | None = None
    placed: bool | None = None  # None: goal or end unknown; distractors: always None


@dataclass
class TaskView:
    """The task's objects for the report's Targets section and the map's styling."""

    targets: list[str] | None  # None: the trace does not say
    targets_from: str
    goals: dict[str, str]
    goals_from: str
    end_from: str
    objects: list[ObjectFate]
    ordered: bool = False
    placed_by_world: int | None = None
    total_by_world: int | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def unplaced(self) -> list[ObjectFate]:
        return [o for o in self.objects if o.role == "target" and o.placed is False]

    @property
    def distractors(self) -> list[ObjectFate]:
        return [o for o in self.objects if o.role == "distractor"]

    def roles(self) -> dict[str, str]:
        return {o.name: o.role for o in self.objects}


def _observations(trace: LoadedTrace) -> list[Observation]:
    out = [m.observation for m in trace.messages(ActionResult)] + [m.observation for m in trace.messages(Turn)]
    out.sort(key=lambda o: o.tick)
    return out


def _generated(started: EpisodeStarted) -> tuple[dict[str, tuple[bool, str | None]], str | None]:
    """name -> (target, goal) from the task's generator, or why not."""
    try:
        task = get_task(started.task)
        placements = task.generate(get_layout(started.scene), started.seed, started.n_objects)
    except Exception as exc:  # an unknown task or scene, an older trace: the page says the goals are unknown
        return {}, f"{type(exc).__name__}: {exc}"
    return {pl.kind.name: (pl.target, task.goal(pl.kind) if pl.target else None) for pl in placements}, None


def _where(pose: ObjectPose | ObjectView) -> str:
    if pose.held_by:
        return f"held by {pose.held_by}"
    if pose.on:
        return f"{'in' if pose.inside else 'on'} {pose.on}"
    return "on the floor"


def task_view(
    trace: LoadedTrace,
    started: EpisodeStarted | None,
    frames: list[Frame],
    frames_from: str,
    metrics: Metrics | None,
) -> TaskView:
    """The task's objects, their roles, goals and ends, from the trace (see the module docstring)."""
    observations = _observations(trace)
    notes: list[str] = []
    done = trace.last(EpisodeDone)
    key = done if done is not None and done.targets else None  # the world's answer key, sent once the episode is over

    targets: list[str] | None = None
    targets_from = ""
    if key is not None:
        targets, targets_from = list(key.targets), "the world (its episode_done event)"
    else:
        for obs in observations:
            if obs.targets:
                targets, targets_from = list(obs.targets), f"{obs.robot}'s observations"
                break
    ordered = any(o.ordered for o in observations) or (key is not None and key.ordered)

    goals: dict[str, str] = {}
    goals_from = ""
    if key is not None and key.goals:
        goals, goals_from = dict(key.goals), "the world (its episode_done event)"
    else:
        for obs in observations:
            if obs.goals:
                goals, goals_from = dict(obs.goals), f"{obs.robot}'s observations"
                break

    generated: dict[str, tuple[bool, str | None]] = {}
    if (targets is None or not goals) and started is not None:
        generated, why = _generated(started)
        gen_targets = [n for n, (t, _) in generated.items() if t]
        if targets is None and gen_targets:
            targets, targets_from = gen_targets, "the task's generator (the trace does not name them)"
        elif targets is not None and generated and set(gen_targets) != set(targets):
            notes.append(
                "the task's generator gives other targets than the trace (another version?): the goals are not known"
            )
            generated = {}
        if why and targets is None:
            notes.append(
                f"the targets are not known: the trace does not name them and the task's generator failed ({why})"
            )
        if not goals and generated:
            goals = {n: g for n, (t, g) in generated.items() if t and g}
            goals_from = "the task's goal for each target"

    # where each object ended
    ends: dict[str, ObjectPose] = {}
    end_from = ""
    if frames_from == "snapshots" and frames:
        ends = dict(frames[-1].objects)
        end_from = f"the last snapshot (tick {frames[-1].tick})"
    seen: dict[str, str] = {}
    for obs in observations:  # the robots' last word on each object, for traces without snapshots
        for o in obs.objects:
            if o.name:
                seen[o.name] = f"{_where(o)} (as {obs.robot} last saw it, tick {obs.tick})"
    if not end_from:
        end_from = "the robots' observations (no snapshots: the ground truth is not in the trace)" if seen else ""

    names: list[str] = list(targets or [])
    others = set(ends) | set(seen) | {n for n in generated if n not in names}
    if frames_from == "snapshots":
        others |= {n for f in frames for n in f.objects}
    names += sorted(others - set(names))
    objects: list[ObjectFate] = []
    for name in names:
        role = (
            "target"
            if targets is not None and name in targets
            else ("distractor" if targets is not None else "unknown")
        )
        fate = ObjectFate(name=name, role=role, goal=goals.get(name))
        pose = ends.get(name)
        if pose is not None:
            fate.where, fate.x, fate.y = _where(pose), pose.x, pose.y
            if role == "target" and fate.goal is not None:
                fate.placed = pose.on == fate.goal and not pose.held_by
        elif name in seen:
            fate.where = seen[name]
        else:
            fate.where = "never seen"
        objects.append(fate)

    placed, total = (metrics.placed, metrics.total) if metrics is not None else (None, None)
    view = TaskView(
        targets=targets,
        targets_from=targets_from,
        goals=goals,
        goals_from=goals_from,
        end_from=end_from,
        objects=objects,
        ordered=ordered,
        placed_by_world=placed,
        total_by_world=total,
        notes=notes,
    )
    mine = sum(1 for o in objects if o.role == "target" and o.placed)
    known = all(o.placed is not None for o in objects if o.role == "target")
    if view.placed_by_world is not None and known and targets and mine != view.placed_by_world:
        why = " (an ordered task: the world counts only the stack's correct prefix)" if ordered else ""
        notes.append(f"{mine} target(s) end on their goal, the world counts {view.placed_by_world} placed{why}")
    return view
