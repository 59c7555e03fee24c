"""One episode in PyBullet: it builds the scene, robots and objects, keeps their physical state
(physics.PhysicalWorld) and runs each action (the step) through the skill registry.

Robots move kinematically (bases set along A* paths, arms set along OMPL plans); a held
object follows the suction cup. Every skill returns a `SkillOutcome` whose feedback sentence
comes from what the planners and checks measured.

Skills act on the real world; what a robot observes is its own memory (observe.Knowledge,
beliefs.py): objects where it last saw them or was told they are, containers open or closed as
it last saw them. Observations, views and snapshots are built in observe.py.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import replace

import numpy as np

from mhrc.core.fidelity import motion_noise, parse_aids
from mhrc.core.logs import get_logger
from mhrc.core.protocol import (
    Action,
    Communicate,
    FurnitureView,
    MotionNoise,
    ObjectPose,
    ObjectView,
    Observation,
    OutcomeCode,
    RobotPose,
    ScenarioEvent,
    SkillOutcome,
    Wait,
)
from mhrc.core.team import PAPER_TEAM, TeamSpec
from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from . import assets, observe
from . import feedback as fb
from .arm import ArmPlanner
from .assets import AssetDir
from .astar import Grid
from .bound import lower_bound, symbolic_episode
from .checks import check_episode
from .dynamics import Dynamics
from .furniture import Fixture, Layout
from .kinds import KINDS, flight_altitude
from .observe import Knowledge, WorldSnapshot
from .physics import ObjectState, PhysicalWorld
from .placement import floor_margin, place_team
from .robots import RobotBody, spawn
from .scenario import Scenario
from .scene import BuiltScene, build_scene, get_layout
from .skills import SKILLS, SkillContext
from .tasks import Seen, TaskResult, get_task
from .teams import check_team

log = get_logger("mhrc.world.sim")


class Sim:
    """The PyBullet world of one episode (p.DIRECT unless gui=True)."""

    def __init__(
        self,
        *,
        task: str = "pack_objects",
        scene: str = "kitchen",
        seed: int = 0,
        n_objects: int = 4,
        gui: bool = False,
        team: TeamSpec = PAPER_TEAM,
        robots: Iterable[str] | None = None,
        aids: tuple[str, ...] | frozenset[str] = (),
        scenario: Scenario | None = None,
        noise: str = "on",
        one_per_stand_pose: bool | None = None,
        visuals: bool = False,
    ) -> None:
        """`scenario`: the events fired during the episode (`fire_events`; dynamics.py); `noise`: on
        (the calibrated motion noise) or off (none: bases stop exactly, releases do not slip).
        `one_per_stand_pose`: a robot cannot navigate to a stand pose another robot stands at (per
        level: floor or air); None: so for any team but the paper's, whose world (like the
        paper's) lets robots share a stand pose, so that it scores as it always did. `visuals`: load
        the robots' visual meshes, for a world a camera renders (`world/render.py`, the video, the
        environment's frames; the GUI always has them). Without them (the default) pybullet_data's
        robots carry their collision meshes alone: the world plays the same, and builds in about a
        third of the time; rendering it is refused (ValueError)."""
        check_episode(task=task, scene=scene, n_objects=n_objects)
        self.aids: frozenset[str] = frozenset(parse_aids(aids))
        # the motion noise's rates (`noise`: on, the calibration, or off); none with the exact_motion aid either
        self.noise: MotionNoise = motion_noise(noise, self.aids)
        # motion noise: its own stream, apart from the generator's, and different for every episode of a seed
        rng = np.random.default_rng([seed, zlib.crc32(f"{task}/{scene}/{n_objects}".encode()), 0x4D485243])
        if one_per_stand_pose is None:  # by the team as given, before an ablation leaves robots out
            one_per_stand_pose = team.digest() != PAPER_TEAM.digest()
        self.one_per_stand_pose = one_per_stand_pose
        if robots is not None:  # an ablation's subset of the team (no_mobile: the paper's team without David)
            unknown = set(robots) - set(team.names)
            if unknown:
                raise ValueError(f"robots {sorted(unknown)} are not in the team {team.name} ({', '.join(team.names)})")
            team = team.without(set(team.names) - set(robots))
        self.task_id, self.scene_id, self.seed, self.n_objects = task, scene, seed, n_objects
        self.task = get_task(task)
        self.layout: Layout = get_layout(scene)
        check_team(team, self.layout)
        self.team = team
        self.robots: tuple[str, ...] = team.names  # the execution order
        self._scenario = scenario
        self.visuals = visuals or gui
        self.cid = p.connect(p.GUI if gui else p.DIRECT)
        self.assets = AssetDir()
        try:
            if gui:
                p.configureDebugVisualizer(p.COV_ENABLE_RENDERING, 0, physicsClientId=self.cid)
            self._build(rng)
            if gui:
                p.configureDebugVisualizer(p.COV_ENABLE_RENDERING, 1, physicsClientId=self.cid)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ building
    def _build(self, rng: np.random.Generator) -> None:
        lay = self.layout
        kinds = [KINDS[r.kind] for r in self.team.robots]
        margin = floor_margin(self.team)  # the floor's grid: ground bases
        fliers = [k.footprint for k in kinds if k.flies]
        fixtures = {fx.name: fx for fx in self.task.fixtures(lay)}
        scene = build_scene(
            self.cid, lay, self.assets, margin, list(fixtures.values()), max(fliers) if fliers else None
        )
        self.world = w = PhysicalWorld(
            self.cid, lay, scene, ArmPlanner(scene.statics, seed=self.seed), fixtures, self.aids
        )
        w.one_per_stand_pose = self.one_per_stand_pose
        mounts = iter(lay.arm_mounts)
        starts = place_team(lay, self.team, self.seed, scene.grid)  # TeamError NO_ROOM when it cannot
        tallest = max(f.size[2] for f in lay.furniture)
        for spec in self.team.robots:
            kind = KINDS[spec.kind]
            if kind.mobile:
                altitude = flight_altitude(kind, tallest) if kind.flies else 0.0
                w.bots[spec.name] = spawn(
                    self.cid,
                    spec.name,
                    kind,
                    self.assets,
                    pose=starts[spec.name],
                    altitude=altitude,
                    visuals=self.visuals,
                )
            else:
                base, yaw = next(mounts)  # check_team: no more fixed arms than mounts
                w.bots[spec.name] = spawn(
                    self.cid, spec.name, kind, self.assets, arm_base=base, arm_yaw=yaw, visuals=self.visuals
                )
        self.targets: list[str] = []
        self.goals: dict[str, str] = {}  # target -> the fixture it must end on
        self.knowledge = Knowledge(w, self.robots, self.aids)
        for pl in self.task.generate(lay, self.seed, self.n_objects):
            k = pl.kind
            path = assets.write_object(self.assets, k.name, k.shape, k.color)
            body = p.loadURDF(path, (0, 0, -5), physicsClientId=self.cid)
            obj = ObjectState(k.name, k, body, pl.furniture, pl.inside, pl.target, local=pl.xy if pl.inside else None)
            w.objects[k.name] = obj
            if pl.target:
                self.targets.append(k.name)
                self.goals[k.name] = self.task.goal(k)
            if pl.inside:
                w.follow_container(obj)
            else:
                f = lay.get(pl.furniture)
                assert f is not None
                w.rest(obj, pl.xy[0], pl.xy[1], f.top)
        self.skill_context = SkillContext(w, self.knowledge, rng, self.noise)  # what the skills act through
        self.dynamics = Dynamics(w, self.task, self.targets, self.goals, self.assets, self.seed, self._scenario)
        log.debug("episode built", task=self.task_id, scene=self.scene_id, seed=self.seed, objects=list(w.objects))

    @property
    def closed(self) -> bool:
        """Whether `close` has begun (the world is stopping): set before the client disconnects, so
        a skill that the disconnect fails in another thread already sees it."""
        return getattr(self, "_closing", False) or self.cid < 0

    def close(self) -> None:
        """Disconnect every PyBullet client and remove the generated assets (idempotent)."""
        self._closing = True
        if self.cid >= 0:
            p.disconnect(self.cid)
            self.cid = -1
        world: PhysicalWorld | None = getattr(self, "world", None)
        if world is not None:
            world.cid = -1
            world.planner.close()
        self.assets.close()

    def __enter__(self) -> Sim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ the step
    @property
    def rng(self) -> np.random.Generator:
        """The motion noise the skills draw from (a test may set another generator)."""
        return self.skill_context.rng

    @rng.setter
    def rng(self, value: np.random.Generator) -> None:
        self.skill_context = replace(self.skill_context, rng=value)

    def capabilities(self, robot: str) -> frozenset[str]:
        return frozenset(self.bots[robot].kind.skills) if robot in self.bots else frozenset()

    def finishers(self) -> frozenset[str]:
        """The robots that may place on the task's goal fixtures (the paper: Bob)."""
        return frozenset(name for name, b in self.bots.items() if b.kind.finishes_task)

    def execute(self, robot: str, action: Action) -> SkillOutcome:
        """Run one action of `robot` (the skill registered for its type). Bad arguments give a
        failure outcome, never an exception."""
        if isinstance(action, Communicate):
            raise ValueError("communicate is handled by the world service, not the simulator")
        if robot not in self.bots:
            return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, fb.no_such_robot(robot, self.robots))
        r = self.bots[robot]
        if action.skill not in r.kind.skills:
            return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, fb.not_capable(robot, action.skill, r.kind.skills))
        if (broken := self.dynamics.broken_for(robot)) and not isinstance(action, Wait):
            return SkillOutcome.fail(
                OutcomeCode.BROKEN_DOWN, fb.broken_down(action.skill, broken), ticks=broken
            )  # ticks: for machines
        run = SKILLS.get(type(action))
        if run is None:  # pragma: no cover - every action but communicate has a skill
            out = SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, f"Unknown skill {action.skill}.")
        else:
            out = run(self.skill_context, r, action)
            self.dynamics.note_containers()
        log.debug("skill", robot=robot, action=action.call(), code=out.code.value, sim_time=round(out.sim_time, 3))
        return out

    def fire_events(self, tick: int) -> list[ScenarioEvent]:
        """Tick `tick` opens: apply the scenario's events due by then (dynamics.py); what each did."""
        return self.dynamics.fire_due(tick)

    # ------------------------------------------------------------------ the physical state (physics.PhysicalWorld)
    @property
    def scene(self) -> BuiltScene:
        return self.world.scene

    @property
    def grid(self) -> Grid:
        return self.world.grid

    @property
    def fixtures(self) -> dict[str, Fixture]:
        return self.world.fixtures

    @property
    def bots(self) -> dict[str, RobotBody]:
        return self.world.bots

    @property
    def objects(self) -> dict[str, ObjectState]:
        return self.world.objects

    @property
    def opening(self) -> dict[str, float]:
        """Container -> joint value."""
        return self.world.opening

    def position(self, obj: ObjectState) -> tuple[float, float, float]:
        return self.world.position(obj)

    def yaw(self, obj: ObjectState) -> float:
        return self.world.yaw(obj)

    def is_open(self, name: str) -> bool:
        return self.world.is_open(name)

    def set_container(self, name: str, value: float) -> None:
        """Slide a drawer to `value` metres open, or swing a lid or door to `value` rad."""
        self.world.set_container(name, value)

    def handle_position(self, name: str) -> tuple[float, float, float]:
        return self.world.handle_position(name)

    def table_top(self) -> float:
        return self.world.table_top()

    def fixture_at(self, x: float, y: float) -> Fixture | None:
        return self.world.fixture_at(x, y)

    def within_handover(self, spot: tuple[float, ...]) -> bool:
        return self.world.within_handover(spot)

    def objects_on(self, furniture: str) -> list[str]:
        return self.world.objects_on(furniture)

    def grasp(self, r: RobotBody, obj: ObjectState) -> None:
        """`r` grips `obj` (and knows it holds it)."""
        self.skill_context.grasp(r, obj)

    def release(
        self,
        r: RobotBody,
        obj: ObjectState,
        spot: tuple[float, float, float],
        yaw: float,
        location: str | None = None,
        error: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """Let go of `obj` over `spot` (see PhysicalWorld.release)."""
        self.world.release(r, obj, spot, yaw, location, error)

    # ------------------------------------------------------------------ knowledge (observe.Knowledge)
    @property
    def known(self) -> dict[str, set[str]]:
        """Robot -> the objects in its scene graph (add to it to let a robot know of an object as it is now)."""
        return self.knowledge.known

    def known_objects(self, robot: str) -> set[str]:
        return self.knowledge.known_objects(robot)

    def belief(self, robot: str, name: str) -> ObjectView | None:
        return self.knowledge.belief(robot, name)

    def learn(self, robot: str, names: Iterable[str]) -> None:
        """`robot` learns of `names` as they are now (a stand-in for a report, for tests and scripts)."""
        self.knowledge.learn(robot, names)

    def tell(self, receiver: str, sender: str, text: str) -> None:
        """A message was delivered: what it tells the receiver's scene graph (observe.Knowledge.tell)."""
        self.knowledge.tell(receiver, sender, text)

    def message(self, receiver: str, sender: str, text: str) -> Callable[[], None]:
        """A message was sent: the call that tells its receiver, when delivered (observe.Knowledge.message)."""
        return self.knowledge.message(receiver, sender, text)

    # ------------------------------------------------------------------ the task
    def lower_bound(self) -> int:
        """A lower bound on the temporal steps any team needs for this episode (see bound.py)."""
        return lower_bound(symbolic_episode(self.world, self.targets))

    def answer_key(self) -> tuple[list[str], dict[str, str], bool]:
        """The task's targets (in task order), each one's goal fixture, and whether they must
        arrive in order: said once the episode is over, for reports (EpisodeDone)."""
        return list(self.targets), dict(self.goals), bool(self.task.ordered)

    def seen(self) -> list[Seen]:
        """Every object's end state as the goal check reads it."""
        return self.world.seen()

    def evaluate(self) -> TaskResult:
        return self.task.evaluate(self.targets, self.seen())

    def task_status(self) -> str:
        return self.task.status(self.targets, self.seen(), self.aids)

    # ------------------------------------------------------------------ views (observe.py)
    def observe(self, robot: str, tick: int) -> Observation:
        """The robot's own partial view; new_messages is left for the world service to fill."""
        return observe.observation(self.world, self.knowledge, self.task, self.targets, self.goals, robot, tick)

    def views(self) -> tuple[list[FurnitureView], list[ObjectView]]:
        """Full ground truth, for observers."""
        return observe.views(self.world)

    def poses(self) -> tuple[dict[str, RobotPose], dict[str, ObjectPose], dict[str, bool]]:
        """Ground truth for viewers (the `snapshot` event): robots, objects, containers."""
        return observe.poses(self.world)

    def apply_snapshot(
        self, robots: Mapping[str, RobotPose], objects: Mapping[str, ObjectPose], open: Mapping[str, bool]
    ) -> None:
        """Teleport bodies to a `snapshot` event's poses (for videos; see observe.apply_snapshot)."""
        observe.apply_snapshot(self.world, robots, objects, open)

    def snapshot(self) -> WorldSnapshot:
        """Every body's pose and robot state, for comparing runs (determinism tests)."""
        return observe.snapshot(self.world)
