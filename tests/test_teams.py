"""Teams as data (issue 33): the spec's parsing and every bad input, the shipped teams, and the
world's check of a team against its kinds and a layout."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mhrc.core.team import PAPER_TEAM, TeamError, TeamProblem, TeamSpec, load_team_file, parse_inline
from mhrc.world.kinds import KINDS
from mhrc.world.scene import get_layout
from mhrc.world.teams import SHIPPED, check_team


def test_the_paper_team_is_alice_bob_david_in_the_papers_order() -> None:
    assert PAPER_TEAM.kinds == {"alice": "mobile_manipulator", "bob": "tabletop_arm", "david": "mobile_base"}
    assert PAPER_TEAM.names == ("alice", "bob", "david") and SHIPPED["paper"] is PAPER_TEAM


def test_inline_robots_keep_their_order() -> None:
    team = parse_inline("alice=mobile_manipulator, bob=tabletop_arm,lucy=drone")
    assert team.names == ("alice", "bob", "lucy") and team.kinds["lucy"] == "drone" and team.name == "custom"


@pytest.mark.parametrize(
    ("inline", "code", "named"),
    [
        ("alice=mobile_manipulator", TeamProblem.SIZE, "not 1"),
        (",".join(f"r{i}=mobile_base" for i in range(9)), TeamProblem.SIZE, "not 9"),
        ("alice=mobile_manipulator,alice=tabletop_arm", TeamProblem.DUPLICATE_NAME, "'alice' appears twice"),
        ("Alice=mobile_manipulator,bob=tabletop_arm", TeamProblem.BAD_NAME, "'Alice'"),
        ("al-ice=mobile_manipulator,bob=tabletop_arm", TeamProblem.BAD_NAME, "'al-ice'"),
        ("alice=mobile_manipulator,bob", TeamProblem.UNKNOWN_TEAM, "'bob' is not name=kind"),
    ],
)
def test_a_bad_inline_team_is_one_line_with_its_code(inline: str, code: TeamProblem, named: str) -> None:
    with pytest.raises(TeamError) as err:
        parse_inline(inline)
    assert err.value.code is code and named in str(err.value) and "\n" not in str(err.value)


def test_a_team_file_in_toml_or_json(tmp_path: Path) -> None:
    toml = tmp_path / "duo.toml"
    toml.write_text(
        'purpose = "two robots"\n'
        '[[robots]]\nname = "alice"\nkind = "mobile_manipulator"\nstart = [1.0, 2.0, 0.5]\nllm = "openai:gpt-4o"\n'
        '[[robots]]\nname = "bob"\nkind = "tabletop_arm"\n'
    )
    team = load_team_file(toml)
    assert team.name == "duo" and team.purpose == "two robots"
    assert team.robot("alice").start == (1.0, 2.0, 0.5) and team.robot("alice").llm == "openai:gpt-4o"
    js = tmp_path / "same.json"
    js.write_text(json.dumps({"robots": [r.model_dump(exclude_none=True) for r in team.robots]}))
    assert load_team_file(js).digest() == team.digest()  # the digest is what the team is, not its name


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("robots = 3", "robots must be a list"),
        (
            '[[robots]]\nname = "alice"\nkind = "mobile_manipulator"\nwheels = 4\n[[robots]]\nname="b"\nkind="x"',
            "wheels",
        ),
        (
            '[[robots]]\nname = "alice"\nkind = "mobile_manipulator"\nstart = [1]\n[[robots]]\nname="b"\nkind="x"',
            "start",
        ),
        ("not toml [", "--team"),
    ],
)
def test_a_bad_team_file_names_the_field(tmp_path: Path, text: str, named: str) -> None:
    path = tmp_path / "t.toml"
    path.write_text(text)
    with pytest.raises(TeamError) as err:
        load_team_file(path)
    assert err.value.code is TeamProblem.BAD_FILE and named in str(err.value) and str(path) in str(err.value)


def test_the_shipped_teams_are_at_least_six_each_with_a_purpose() -> None:
    assert len(SHIPPED) >= 6 and {"paper", "no_mobile", "two_fetchers", "drone_scout", "large"} <= set(SHIPPED)
    for name, team in SHIPPED.items():
        assert team.name == name and team.purpose and "\n" not in team.purpose
    large = SHIPPED["large"].kinds
    assert sorted(large.values()) == sorted(
        ["mobile_manipulator"] * 2 + ["mobile_base"] * 2 + ["drone", "tabletop_arm"]
    )
    assert max(len(t.robots) for t in SHIPPED.values()) == 8


def test_the_world_refuses_a_team_it_cannot_run() -> None:
    kitchen = get_layout("kitchen")
    check_team(PAPER_TEAM, kitchen)
    cases = [
        ("alice=mobile_manipulator,david=mobile_base", TeamProblem.NO_FINISHER, "tabletop_arm"),
        ("bob=tabletop_arm,david=mobile_base", TeamProblem.NO_FETCHER, "mobile_manipulator"),
        ("alice=mobile_manipulator,bob=tabletop_arm,rex=tank", TeamProblem.UNKNOWN_KIND, ", ".join(KINDS)),
        ("alice=mobile_manipulator,bob=tabletop_arm,ann=tabletop_arm", TeamProblem.TOO_MANY_ARMS, "1 arm mount"),
    ]
    for inline, code, named in cases:
        with pytest.raises(TeamError) as err:
            check_team(parse_inline(inline), kitchen)
        assert err.value.code is code and named in str(err.value), inline


def test_a_team_spec_is_frozen_and_checked_when_built_in_code() -> None:
    with pytest.raises(ValueError, match="appears twice"):
        TeamSpec(robots=PAPER_TEAM.robots + PAPER_TEAM.robots[:1])
    assert PAPER_TEAM.without({"david"}).names == ("alice", "bob")


# ------------------------------------------------------------------------- the command line
BAD_TEAMS = [
    ("alice=mobile_manipulator,david=mobile_base", "nobody can finish the task"),
    ("alice=mobile_manipulator,alice=tabletop_arm", "'alice' appears twice"),
    ("alice=mobile_manipulator,bob=tabletop_arm,rex=tank", "the kinds are mobile_manipulator, tabletop_arm"),
    ("alice=mobile_manipulator,bob=tabletop_arm,ann=tabletop_arm", "arm mount"),
    ("alice=mobile_manipulator,Bob=tabletop_arm", "not a lowercase identifier"),
    ("nosuchteam", "not a shipped team (paper, no_mobile"),
]


@pytest.mark.parametrize(("team", "named"), BAD_TEAMS)
def test_a_team_that_cannot_run_is_refused_before_anything_starts(tmp_path: Path, team: str, named: str) -> None:
    from test_bad_input import _mhrc, _refused

    line = _refused(_mhrc("up", "--team", team, cwd=tmp_path), "--team")
    assert named in line
    assert list(tmp_path.iterdir()) == []  # no run directory, no trace


def test_mhrc_teams_lists_every_shipped_team_with_its_purpose(tmp_path: Path) -> None:
    from test_bad_input import _mhrc

    done = _mhrc("teams", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    for name, team in SHIPPED.items():
        assert f"{name} " in done.stdout and team.purpose in done.stdout
    kinds = _mhrc("teams", "--kinds", cwd=tmp_path)
    assert all(k in kinds.stdout for k in KINDS)


def test_an_agent_for_a_robot_outside_the_team_is_refused(tmp_path: Path) -> None:
    from test_bad_input import _mhrc, _refused

    done = _mhrc("agent", "--robot", "carol", "--connect", "tcp/127.0.0.1:9", "--insecure", cwd=tmp_path)
    assert "not in this episode's team" in _refused(done, "--robot")


def test_the_paper_teams_child_processes_get_the_argv_they_always_had() -> None:
    from mhrc.run.config import EpisodeConfig
    from mhrc.run.processes import agent_command, world_command

    paper = EpisodeConfig.build(run="r1", port=7447)
    assert "--team" not in world_command(paper) and "--team" not in agent_command("alice", paper)
    duo = EpisodeConfig.build(run="r1", port=7447, team=parse_inline("ann=mobile_manipulator,bob=tabletop_arm"))
    argv = world_command(duo)
    from mhrc.run.teams import resolve_team

    assert resolve_team(argv[argv.index("--team") + 1]) == duo.team
    assert duo.robots == ("ann", "bob") and EpisodeConfig.build(
        team=SHIPPED["two_fetchers"], ablation="no_mobile"
    ).robots == (
        "alice",
        "bob",
        "carol",
    )


def test_every_robot_of_a_team_of_eight_has_a_colour_of_its_own() -> None:
    from rich.console import Console

    from mhrc.run.console import ProgressPrinter
    from mhrc.viewer.page import ROBOT_COLORS, distinct, robot_colors
    from mhrc.viewer.video import PALETTE as VIDEO
    from mhrc.viewer.video import ROBOT_COLORS as VIDEO_NAMED

    for names in (list(SHIPPED["full_house"].names), [f"r{i}" for i in range(8)]):
        assert len(set(robot_colors(names).values())) == 8
        assert len(set(distinct(names, VIDEO_NAMED, VIDEO).values())) == 8
        printer = ProgressPrinter(Console(file=None, record=True), verbose=False)
        assert len({printer._robot(n).split("]")[0] for n in names}) == 8
    assert robot_colors(["alice", "bob", "david"]) == ROBOT_COLORS  # the paper's team as before


def test_a_team_the_layout_cannot_place_is_refused_before_anything_starts(tmp_path: Path) -> None:
    """Two robots a team file starts on one spot: `mhrc up` refuses it in one line, exit 2, with no
    run directory written (the placement is checked with the config, without building the world)."""
    from test_bad_input import _mhrc, _refused

    team = tmp_path / "crowded.toml"
    team.write_text(
        '[[robots]]\nname = "alice"\nkind = "mobile_manipulator"\nstart = [-1.0, 0.0, 0.0]\n'
        '[[robots]]\nname = "bob"\nkind = "tabletop_arm"\n'
        '[[robots]]\nname = "carol"\nkind = "mobile_manipulator"\nstart = [-1.0, 0.0, 0.0]\n'
    )
    line = _refused(_mhrc("up", "--team", str(team), cwd=tmp_path), "--team")
    assert "carol" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crowded.toml"]
