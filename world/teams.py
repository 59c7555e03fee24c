"""The shipped teams (`mhrc teams`) and the world's check of any team against its robot kinds
and a layout: a team the world cannot run is refused before anything is built, with one line
naming the problem (mhrc.core.team.TeamError, with its code).

A robot's part follows from what its kind can do, never from its name: the finisher places on the
task's goal fixtures (a tabletop arm, the paper's Bob), a fetcher navigates and picks (Alice), a
scout only navigates (David, and a drone)."""

from __future__ import annotations

from mhrc.core.team import PAPER_TEAM, RobotSpec, TeamError, TeamProblem, TeamSpec

from .furniture import Layout
from .kinds import KINDS, RobotKind

__all__ = ["SHIPPED", "check_team", "fetches", "kind_of", "scouts"]


def _team(name: str, purpose: str, *robots: tuple[str, str]) -> TeamSpec:
    return TeamSpec(name=name, purpose=purpose, robots=tuple(RobotSpec(name=n, kind=k) for n, k in robots))


MM, ARM, BASE, DRONE = "mobile_manipulator", "tabletop_arm", "mobile_base", "drone"

# In execution order: fetchers, the finisher, scouts (the paper's Alice, Bob, David).
SHIPPED: dict[str, TeamSpec] = {
    t.name: t
    for t in (
        PAPER_TEAM,
        _team(
            "no_mobile",
            "the paper's no_mobile ablation as a team: Alice and Bob without David",
            ("alice", MM),
            ("bob", ARM),
        ),
        _team(
            "two_fetchers",
            "what a second fetcher buys: the paper's trio and Carol, a second mobile manipulator",
            ("alice", MM),
            ("bob", ARM),
            ("carol", MM),
            ("david", BASE),
        ),
        _team(
            "drone_scout",
            "does a drone scout beat a ground scout: the paper's trio with Lucy, a drone, in David's place",
            ("alice", MM),
            ("bob", ARM),
            ("lucy", DRONE),
        ),
        _team(
            "scout_and_drone",
            "what a drone adds beside the ground scout: the paper's trio and Lucy, a drone",
            ("alice", MM),
            ("bob", ARM),
            ("david", BASE),
            ("lucy", DRONE),
        ),
        _team(
            "large",
            "a large team: two fetchers, two ground scouts, a drone and the arm",
            ("alice", MM),
            ("bob", ARM),
            ("carol", MM),
            ("david", BASE),
            ("erin", BASE),
            ("lucy", DRONE),
        ),
        _team(
            "full_house",
            "the most robots a team may have (8): three fetchers, two ground scouts, two drones and the arm",
            ("alice", MM),
            ("bob", ARM),
            ("carol", MM),
            ("frank", MM),
            ("david", BASE),
            ("erin", BASE),
            ("lucy", DRONE),
            ("mia", DRONE),
        ),
    )
}


def kind_of(spec: RobotSpec) -> RobotKind:
    """The robot's kind; TeamError listing the kinds for one the world does not have."""
    try:
        return KINDS[spec.kind]
    except KeyError:
        raise TeamError(
            TeamProblem.UNKNOWN_KIND,
            f"--team: robot {spec.name!r} has kind {spec.kind!r}; the kinds are {', '.join(KINDS)}",
        ) from None


def fetches(kind: RobotKind) -> bool:
    """A kind that can bring an object to the finisher: it navigates and picks."""
    return {"navigate", "pick"} <= set(kind.skills)


def check_team(team: TeamSpec, layout: Layout | None = None) -> None:
    """TeamError unless the world can run `team` (on `layout`, when given): every kind known,
    someone to finish the task and someone to fetch, no more fixed arms than the layout's arm
    mounts."""
    kinds = {r.name: kind_of(r) for r in team.robots}
    if not any(k.finishes_task for k in kinds.values()):
        finishers = ", ".join(k.id for k in KINDS.values() if k.finishes_task)
        raise TeamError(
            TeamProblem.NO_FINISHER,
            f"--team {team.name}: nobody can finish the task: a team needs a robot of kind {finishers}",
        )
    if not any(fetches(k) for k in kinds.values()):
        fetchers = ", ".join(k.id for k in KINDS.values() if fetches(k))
        raise TeamError(
            TeamProblem.NO_FETCHER,
            f"--team {team.name}: nobody can bring objects to the table: a team needs a robot of kind {fetchers}",
        )
    if layout is not None:
        arms = [n for n, k in kinds.items() if not k.mobile]
        if len(arms) > len(layout.arm_mounts):
            raise TeamError(
                TeamProblem.TOO_MANY_ARMS,
                f"--team {team.name}: {len(arms)} fixed arms ({', '.join(arms)}) but the {layout.name} layout "
                f"has {len(layout.arm_mounts)} arm mount(s)",
            )


def scouts(team: TeamSpec) -> frozenset[str]:
    """The robots that only navigate (no arm): what the paper's no_mobile ablation leaves out."""
    return frozenset(
        r.name for r in team.robots if r.kind in KINDS and KINDS[r.kind].mobile and not KINDS[r.kind].has_arm
    )
