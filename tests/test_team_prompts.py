"""Prompts per kind (issue 33): any team's robots get their kind's templates, filled with their
names and the teammates their part talks to (mhrc.agents.crew); the paper's team renders as
before (its goldens are tests/test_prompts.py's).

The observations are hand-built (mhrc.testing.observation, renamed for robots it does not know),
so these tests need no world, except the one of the world's task texts for a team with two
fetchers.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from mhrc.agents.crew import KIND_PROMPTS, TALKS_TO, crew_of, fill
from mhrc.agents.llm import ScriptedClient
from mhrc.agents.llm_policy import LLMPolicy, load_hints, load_template, template_source
from mhrc.agents.parse import signature
from mhrc.core.protocol import Observation, RobotStatus
from mhrc.core.team import PAPER_TEAM, RobotSpec, TeamSpec
from mhrc.testing import PolicyHarness, observation
from mhrc.world.kinds import KINDS
from mhrc.world.teams import SHIPPED

DRONE_SKILLS = ["navigate", "communicate", "wait"]  # the drone: navigate, communicate, wait
LIKE = {"mobile_manipulator": "alice", "tabletop_arm": "bob", "mobile_base": "david", "drone": "david"}


def obs_of(robot: str, team: TeamSpec, tick: int = 0) -> Observation:
    """A hand-built observation of `robot` in `team`: the default one of a paper robot of its
    part, renamed, with its kind's skills and the team's other robots as its teammates."""
    kinds = team.kinds
    o = observation(LIKE[kinds[robot]], tick=tick)
    skills = {r: DRONE_SKILLS if k == "drone" else list(KINDS[k].skills) for r, k in kinds.items()}
    status = RobotStatus(**(o.status.model_dump() | {"name": robot, "kind": kinds[robot], "skills": skills[robot]}))
    return o.model_copy(
        update={"robot": robot, "status": status, "teammates": {r: s for r, s in skills.items() if r != robot}}
    )


def system_of(robot: str, team: TeamSpec, **options: object) -> str:
    policy = LLMPolicy(robot, ScriptedClient([]), team=team, **options)  # type: ignore[arg-type]
    return policy.render(obs_of(robot, team))[0]["content"]


def section(text: str, head: str) -> str:
    return text.split(f"## {head}\n", 1)[1].split("\n## ", 1)[0]


def numbered(text: str) -> list[int]:
    return [int(n) for n in re.findall(r"^(\d+)\. ", text, re.M)]


# --------------------------------------------------------------------------- who talks to whom


def test_who_talks_to_whom_is_the_papers_for_its_team_and_symmetric_for_every_team() -> None:
    assert {r: crew_of(r).groups["contacts"] for r in PAPER_TEAM.names} == {
        "alice": ("bob", "david"),
        "bob": ("alice",),
        "david": ("alice",),
    }
    assert TALKS_TO == {
        "finisher": ("fetcher",),
        "fetcher": ("finisher", "fetcher", "scout"),
        "scout": ("fetcher", "scout"),
    }
    for team in SHIPPED.values():
        crews = {r: crew_of(r, team) for r in team.names}
        for a, crew in crews.items():
            assert a not in crew.groups["contacts"]
            for b in crew.groups["contacts"]:
                assert a in crews[b].groups["contacts"], (team.name, a, b)
            if crew.role == "finisher":  # the finisher and the scouts do not talk
                assert not set(crew.groups["contacts"]) & set(crew.groups["scouts"])


def test_every_kind_of_the_world_has_its_templates_and_each_loads() -> None:
    assert set(KINDS) <= set(KIND_PROMPTS), "a robot kind without prompts: add it to KIND_PROMPTS and prompts/"
    team = SHIPPED["full_house"]
    for kind in KIND_PROMPTS:
        robot = next(r for r, k in team.kinds.items() if k == kind)
        for part in ("system", "user", "hints"):
            found = template_source(robot, part, team=team)
            assert found is not None and found[1] == f"mhrc.prompts/{kind}_{part}.txt"
            load_template(robot, part, team=team)  # placeholders as the part allows
        assert load_hints(robot, team=team).startswith("## Hints\n")


def test_a_line_naming_a_group_the_team_lacks_is_left_out_and_the_list_closes_up() -> None:
    text = "1. Ask $finisher.\n2. Send $scouts out.\n3. Wait.\n\n1. Tell $fetchers_them.\n2. Cost: $$3 for $robot.\n"
    filled = fill(text, {"finisher": "Bob", "robot": "Alice", "scouts": ""}, frozenset({"scouts", "fetchers"}))
    assert filled == "1. Ask Bob.\n2. Wait.\n\n1. Cost: $$3 for Alice.\n"
    assert fill("1. $a\n3. $b\n", {"a": "x$"}) == "1. x$$\n3. $b\n"  # nothing left out: nothing renumbered


# --------------------------------------------------------------------------- teams


def test_two_fetchers_carol_knows_bob_the_other_fetcher_and_the_scout() -> None:
    team = SHIPPED["two_fetchers"]
    carol = system_of("carol", team)
    assert carol.startswith("You are Carol, a smart robot that can both navigate through the house and manipulate")
    background, constraints = section(carol, "Background"), section(carol, "Constraints")
    assert background.startswith(
        "You work on the task together with Bob, Alice and David, cooperating and communicating with them. "
        "Bob is a robot arm on a table that can manipulate objects; "
        "Alice is a mobile manipulator that can navigate through the house and manipulate objects; "
        "David is a mobile base that can navigate."
    )
    assert "ask him whether he needs your help" in constraints and "tell Bob right away" in constraints
    assert "you may give David the objects" in constraints
    assert "Agree with Alice who fetches which object: tell Alice which one you go for" in constraints
    assert numbered(constraints) == [1, 2, 3, 4, 5, 6]
    # and Alice's names Carol the same way; Bob's the two fetchers, David's the two he follows
    alice = section(system_of("alice", team), "Background")
    assert "Bob, Carol and David" in alice and "Carol is a mobile manipulator" in alice
    bob = system_of("bob", team)
    assert (
        "together with Alice and Carol, cooperating and communicating with them. Unlike you, Alice and Carol can" in bob
    )
    assert "ask Alice or Carol for help: they can navigate" in bob and "David" not in bob
    david = system_of("david", team)
    assert "You do what Alice or Carol asks of you" in david and "Follow Alice and Carol's instructions" in david
    assert "Bob" not in david and "Agree with" not in david  # no other scout: no claims line
    assert numbered(section(david, "Constraints")) == [1, 2]


async def test_bobs_first_step_names_every_fetcher() -> None:
    team = SHIPPED["two_fetchers"]
    d = await PolicyHarness(LLMPolicy("bob", ScriptedClient(["Command: wait()"]), team=team)).decide(
        obs_of("bob", team)
    )
    assert (
        "- (latest) step 0: This is the first step of the task: do nothing else now; communicate with Alice and Carol"
        in (d.prompt or "")
    )


async def test_drone_scout_lucy_is_offered_exactly_her_skills() -> None:
    team = SHIPPED["drone_scout"]
    harness = PolicyHarness(LLMPolicy("lucy", ScriptedClient(["Command: navigate(table_1, 0)"]), team=team))
    d = await harness.decide(obs_of("lucy", team))
    assert d.action.call() == "navigate(table_1, 0)"
    prompt = d.prompt or ""
    assert prompt.startswith("You are Lucy, a smart robot that can fly through the house.")
    skills = section(prompt, "Skills").strip().splitlines()
    assert [line.split(":")[0] for line in skills] == [f"- {signature(s)}" for s in DRONE_SKILLS]
    assert "fly to the stand pose" in skills[0]
    for other in ("move", "open", "pick", "place"):
        assert signature(other).split("(")[0] + "(" not in prompt.split("# Scene graph")[0], other
    profile = section(prompt, "Profile")
    assert (
        "You fly above the furniture" in profile
        and "You cannot open anything, and you cannot pick up or place" in profile
    )
    background = section(prompt, "Background")
    assert background.startswith(
        "You work on the task together with Alice, cooperating and communicating with her. "
        "Alice can navigate through the house and manipulate objects. You do what Alice asks of you"
    )
    assert "Bob" not in prompt.split("# Scene graph")[0] and "Gripper" not in prompt
    # Alice knows Lucy as a drone and may send her; Bob does not know her
    alice = system_of("alice", team)
    assert "Lucy is a drone that can fly over the furniture and see the surfaces from above." in alice
    assert "you may give Lucy the objects" in alice and "David" not in alice
    assert "Lucy" not in system_of("bob", team)


def test_a_drone_beside_a_ground_scout_claims_surfaces_with_it() -> None:
    team = SHIPPED["scout_and_drone"]
    lucy, david = system_of("lucy", team), system_of("david", team)
    assert "Agree with David which surfaces each of you explores" in section(lucy, "Constraints")
    assert "Agree with Lucy which surfaces each of you explores" in section(david, "Constraints")
    assert "Lucy can fly over the furniture" in section(david, "Background")
    assert numbered(section(lucy, "Constraints")) == [1, 2, 3]


def test_the_large_team_each_robot_names_whom_its_part_talks_to() -> None:
    team = SHIPPED["large"]
    names = {r.capitalize() for r in team.names}
    for robot in team.names:
        crew = crew_of(robot, team)
        text = system_of(robot, team, prompt_hints=True)
        system = text.split("## Skills")[0].split("## Hints")[0]
        background = section(system, "Background")
        contacts = {c.capitalize() for c in crew.groups["contacts"]}
        for name in names - {robot.capitalize()}:
            assert (name in background) is (name in contacts), (robot, name)
        for head in ("Profile", "Constraints"):
            assert numbered(section(system, head)) == list(range(1, len(numbered(section(system, head))) + 1))
        assert "$" not in text
    erin = system_of("erin", team)
    assert "Erin" not in section(erin, "Background") and "Agree with David and Lucy which surfaces" in erin
    assert "Lucy is a drone" in section(system_of("alice", team), "Background")


def test_a_team_without_scouts_leaves_out_what_the_fetcher_would_send_them() -> None:
    team = SHIPPED["no_mobile"]
    alice = system_of("alice", team, prompt_hints=True)
    assert "David" not in alice and "you may give" not in alice and "hand the open surfaces" not in alice
    assert section(alice, "Background").startswith(
        "You work on the task together with Bob, cooperating and communicating with him. "
        "Bob is a robot arm on a table that can manipulate objects.\n"
    )
    assert numbered(section(alice, "Constraints")) == [1, 2, 3, 4]
    # the paper's no_mobile ablation is the paper's team with David absent: his prompt as before, and the note
    ablation = system_of("alice", PAPER_TEAM, teammates_absent=("david",))
    assert "you may give David the objects" in ablation and "David is not part of the team in this episode." in ablation


def test_a_robot_outside_its_team_or_of_a_kind_without_prompts_is_refused() -> None:
    with pytest.raises(ValueError, match="robot 'carol' is not in team paper"):
        LLMPolicy("carol", ScriptedClient([]))
    odd = TeamSpec(robots=(RobotSpec(name="bob", kind="tabletop_arm"), RobotSpec(name="rex", kind="legged")))
    with pytest.raises(
        ValueError, match="no prompts for robot kind.* legged .*the kinds with prompts are mobile_manipulator"
    ):
        LLMPolicy("bob", ScriptedClient([]), team=odd)


# --------------------------------------------------------------------------- --prompts DIR


def test_prompts_dir_the_robots_file_over_its_kinds_over_the_built_in(tmp_path: Path) -> None:
    team = SHIPPED["two_fetchers"]
    (tmp_path / "mobile_manipulator_system.txt").write_text(
        "Kind file: you are $robot; ask $finisher.\n$skills\n", encoding="utf-8"
    )
    (tmp_path / "carol_system.txt").write_text("Carol's own file: you are $robot.\n$skills\n", encoding="utf-8")
    (tmp_path / "mobile_manipulator_hints.txt").write_text("## Hints\n- Kind hints for $robot.\n", encoding="utf-8")
    (tmp_path / "alice_hints.txt").write_text("## Hints\n- Alice's own hints, $fetchers.\n", encoding="utf-8")
    (tmp_path / "mobile_base_user.txt").write_text(
        "Kind user file.\n$scene_graph\n$status\n$task\n$feedback\n$messages\n$actions\n", encoding="utf-8"
    )
    where = {
        (r, part): (template_source(r, part, tmp_path, team=team) or ("", ""))[1]
        for r in team.names
        for part in ("system", "user", "hints")
    }
    assert where[("carol", "system")] == str(tmp_path / "carol_system.txt")  # the robot's own
    assert where[("alice", "system")] == str(tmp_path / "mobile_manipulator_system.txt")  # its kind's
    assert where[("bob", "system")] == "mhrc.prompts/tabletop_arm_system.txt"  # the built-in
    assert where[("alice", "hints")] == str(tmp_path / "alice_hints.txt")
    assert where[("carol", "hints")] == str(tmp_path / "mobile_manipulator_hints.txt")
    assert where[("david", "user")] == str(tmp_path / "mobile_base_user.txt")
    assert where[("david", "system")] == "mhrc.prompts/mobile_base_system.txt"

    def render(robot: str) -> list[str]:
        policy = LLMPolicy(robot, ScriptedClient([]), team=team, prompts_dir=tmp_path, prompt_hints=True)
        return [m["content"] for m in policy.render(obs_of(robot, team))]

    (carol_sys, _), (alice_sys, _), (bob_sys, _), (david_sys, david_user) = (
        render(r) for r in ("carol", "alice", "bob", "david")
    )
    assert carol_sys.startswith("Carol's own file: you are Carol.\n") and "Kind hints for Carol." in carol_sys
    assert alice_sys.startswith("Kind file: you are Alice; ask Bob.\n") and "Alice's own hints, Carol." in alice_sys
    assert bob_sys == system_of("bob", team, prompt_hints=True)  # nothing of his in the directory
    assert david_user.startswith("Kind user file.\nFurniture:")
    assert david_sys == system_of("david", team, prompt_hints=True)


# --------------------------------------------------------------------------- the world's task texts


def test_the_task_texts_of_a_team_with_two_fetchers_send_to_either() -> None:
    from mhrc.world.sim import Sim

    team = TeamSpec(
        name="two",
        robots=PAPER_TEAM.robots + (RobotSpec(name="carol", kind="mobile_manipulator", start=(0.0, 0.0, 0.0)),),
    )
    sim = Sim(team=team, seed=0)
    try:
        bob, david, carol = (sim.observe(r, 0) for r in ("bob", "david", "carol"))
    finally:
        sim.close()
    assert "ask Alice or Carol to move it for you" in bob.task_detail
    assert "ask Alice or Carol to search for them" in bob.task_detail
    assert (
        david.task_detail.startswith("Do as Alice or Carol arranges:")
        and "tell Alice or Carol about" in david.task_detail
    )
    assert carol.task_brief == "Explore the whole house and hand Bob the objects the task needs."
    paper = Sim(seed=0)
    try:
        assert paper.observe("david", 0).task_detail.startswith("Do as Alice arranges:")
    finally:
        paper.close()
