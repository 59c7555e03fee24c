"""The team as an axis of `mhrc eval` (issue 33): the grid's keys and identity, each team checked
once before anything starts, rows that record the team (older rows read as the paper's), summaries
that never average across teams and read as before for the paper's alone, the team comparison and
its plot; and a real two-team grid (the paper's trio and no_mobile, heuristic)."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from json_rows import records

from mhrc.analysis.metrics import from_trace
from mhrc.core.team import PAPER_TEAM
from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.eval.html import against_team_size, page
from mhrc.eval.records import EvalManifest, read_manifest, read_rows, upgrade_row
from mhrc.eval.report import csv_text, markdown
from mhrc.eval.rows import setting_label, setting_of
from mhrc.eval.spec import EvalIdentity
from mhrc.eval.summary import Summary
from mhrc.run.config import ConfigError
from mhrc.run.teams import resolve_team

NO_MOBILE = resolve_team("no_mobile")
TINY = dict(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,))
PAPER_KINDS = {"alice": "mobile_manipulator", "bob": "tabletop_arm", "david": "mobile_base"}


# --------------------------------------------------------------------------- the grid


def test_the_paper_teams_keys_stay_and_other_teams_are_prefixed() -> None:
    default = EvalSpec(**{**TINY, "objects": (3, 4)})  # type: ignore[arg-type]
    assert [j.key for j in default.jobs()] == ["pack_objects/kitchen/3/0", "pack_objects/kitchen/4/0"]
    assert default.teams == (PAPER_TEAM,) and all(j.config.team == PAPER_TEAM for j in default.jobs())
    two = EvalSpec(**TINY, teams=(PAPER_TEAM, NO_MOBILE), repeats=2)  # type: ignore[arg-type]
    jobs = two.jobs()
    assert [j.key for j in jobs] == [
        "pack_objects/kitchen/3/0",
        "no_mobile/pack_objects/kitchen/3/0",
        "pack_objects/kitchen/3/1",
        "no_mobile/pack_objects/kitchen/3/1",
    ]
    assert [j.config.team.name for j in jobs] == ["paper", "no_mobile"] * 2
    assert jobs[1].config.robots == ("alice", "bob")


def test_the_identity_holds_the_teams_and_an_old_manifest_ran_the_papers() -> None:
    default = EvalSpec(**TINY).identity()  # type: ignore[arg-type]
    old = EvalIdentity.model_validate({k: v for k, v in default.model_dump().items() if k != "teams"})
    assert old == default and default.teams == (f"paper@{PAPER_TEAM.digest()}",)
    a = EvalSpec(**TINY, teams=(PAPER_TEAM, NO_MOBILE)).identity()  # type: ignore[arg-type]
    b = EvalSpec(**TINY, teams=(NO_MOBILE, PAPER_TEAM)).identity()  # type: ignore[arg-type]
    assert a == b != default  # the order the teams were given in does not matter, which teams do
    with_model = PAPER_TEAM.model_copy(
        update={
            "name": "mine",
            "robots": (PAPER_TEAM.robots[0].model_copy(update={"llm": "openai:gpt-4o"}), *PAPER_TEAM.robots[1:]),
        }
    )
    assert "alice=openai:gpt-4o" in EvalSpec(**TINY, teams=(with_model,)).identity().teams[0]  # type: ignore[arg-type]


def test_the_manifest_round_trips_the_teams(tmp_path: Path) -> None:
    spec = EvalSpec(**TINY, teams=(PAPER_TEAM, NO_MOBILE))  # type: ignore[arg-type]
    (tmp_path / "eval.json").write_text(EvalManifest(identity=spec.identity(), spec=spec).text())
    back = read_manifest(tmp_path / "eval.json")
    assert back.spec == spec and back.identity == spec.identity()


@pytest.mark.parametrize(
    ("teams", "message"),
    [
        ((NO_MOBILE, NO_MOBILE), "two teams are named 'no_mobile'"),
        ((NO_MOBILE.model_copy(update={"name": "my team"}),), "'my team' must be letters, digits, _ or -"),
        ((NO_MOBILE.model_copy(update={"name": "paper"}),), "a team named 'paper' must be the paper's"),
        ((resolve_team("alice=mobile_manipulator,bob=tabletop_arm,carol=tabletop_arm"),), "2 fixed arms (bob, carol)"),
        ((resolve_team("alice=mobile_base,bob=tabletop_arm"),), "nobody can bring objects to the table"),
        ((), "--team must each name at least one value"),
    ],
)
def test_each_team_is_checked_once_before_anything_starts(teams: tuple[Any, ...], message: str) -> None:
    with pytest.raises(ConfigError) as exc:
        EvalSpec(**TINY, teams=teams).validate()  # type: ignore[arg-type]
    assert message in str(exc.value)


def test_a_bad_team_on_the_command_line_is_one_line_and_exit_2(tmp_path: Path) -> None:
    for team, message in (
        ("nope", "not a shipped team"),
        ("alice=mobile_base,bob=tabletop_arm", "nobody can bring objects"),
    ):
        out = subprocess.run(
            [sys.executable, "-m", "mhrc", "eval", "--out", str(tmp_path / "x"), "--team", "paper", "--team", team],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 2 and message in out.stderr, out.stderr
        assert not (tmp_path / "x").exists()


# --------------------------------------------------------------------------- rows


def _row(key: str, **extra: Any) -> dict[str, Any]:
    """A finished heuristic row as episodes.jsonl holds it (no team: written before teams)."""
    robots = extra.pop("robots", ["alice", "bob", "david"])
    return {
        "key": key,
        "method": "heuristic",
        "ablation": "none",
        "task": "pack_objects",
        "scene": "kitchen",
        "seed": int(key.rsplit("/", 1)[1]),  # the key's own (a row whose key is another episode's is refused)
        "n_objects": 3,
        "robots": robots,
        "reason": "success",
        "success": True,
        "placed": 3,
        "total": 3,
        "partial_success": 1.0,
        "temporal_steps": 10,
        "action_steps": 20,
        "action_steps_per_robot": dict.fromkeys(robots, 20 // len(robots)),
        "active_ticks": 9,
        "lower_bound": 7,
        "failed_actions": {},
        "messages": 2,
        "llm_calls": 0,
        "prompt_tokens": 0,
        "completion_tokens": 0,
        "wall_time": 1.0,
        "fidelity": "paper",
        "horizon": 50,
        "schedule": "sequential",
        **extra,
    }


def _team_fields(name: str, kinds: dict[str, str], digest: str, moves: dict[str, int], comm: int) -> dict[str, Any]:
    return {
        "team": name,
        "team_digest": digest,
        "team_kinds": kinds,
        "messages_per_robot": dict.fromkeys(kinds, 1),
        "moves_per_robot": moves,
        "communication_steps": comm,
        "redundant_navigations": 1,
        "redundant_picks": 0,
        "redundant_per_robot": dict.fromkeys(kinds, 0),
    }


def test_an_old_row_reads_as_the_papers_team(tmp_path: Path) -> None:
    lines = [
        _row("pack_objects/kitchen/3/0"),
        _row("pack_objects/kitchen/3/1", ablation="no_mobile", robots=["alice", "bob"]),
    ]
    (tmp_path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    trio, duo = read_rows(tmp_path / "episodes.jsonl")
    t, d = trio.metrics, duo.metrics
    assert (t.team, t.team_digest, t.team_kinds) == ("paper", PAPER_TEAM.digest(), PAPER_KINDS)
    assert (d.team, d.team_kinds) == ("paper", {"alice": "mobile_manipulator", "bob": "tabletop_arm"})
    assert d.team_digest == PAPER_TEAM.without({"david"}).digest()
    assert "moves_per_robot" not in trio.flat() and "communication_steps" not in trio.flat()  # unknown, never zero
    # the paper's team, however an ablation cut it, is no setting of its own: labels read as before
    assert setting_of(trio) == setting_of(
        upgrade_row({k: v for k, v in trio.flat().items() if not k.startswith("team")})
    )
    assert setting_label(setting_of(trio)) == "heuristic · ablation none · paper"
    assert setting_label(setting_of(duo)) == "heuristic · ablation no_mobile · paper"
    # a team of the same robots under another name is another setting
    custom = trio.model_copy(update={"metrics": t.model_copy(update={"team": "custom"})})
    assert setting_label(setting_of(custom)).endswith(f"· team custom@{PAPER_TEAM.digest()}")


def _summaries(rows: list[dict[str, Any]]) -> tuple[Summary, str, str]:
    summary = Summary.of([upgrade_row(r) for r in rows], resamples=50)
    return summary, markdown(summary), csv_text(summary)


def test_summaries_never_average_across_teams_and_read_as_before_for_the_papers_alone() -> None:
    paper = [
        {
            **_row(f"pack_objects/kitchen/3/{i}"),
            **_team_fields("paper", PAPER_KINDS, PAPER_TEAM.digest(), {"alice": 2, "bob": 2, "david": 0}, 4),
        }
        for i in range(2)
    ]
    duo_kinds = {"alice": "mobile_manipulator", "bob": "tabletop_arm"}
    duo = [
        {
            **_row(
                f"no_mobile/pack_objects/kitchen/3/{i}",
                robots=["alice", "bob"],
                temporal_steps=20,
                success=False,
                active_ticks=15,
            ),
            **_team_fields("no_mobile", duo_kinds, NO_MOBILE.digest(), {"alice": 3, "bob": 1}, 0),
        }
        for i in range(2)
    ]
    old_paper = [
        {
            k: v
            for k, v in r.items()
            if not k.startswith("team")
            and k not in ("messages_per_robot", "moves_per_robot", "communication_steps")
            and not k.startswith("redundant")
        }
        for r in paper
    ]
    # the paper's team alone: the same markdown and csv as rows written before teams, and no team column
    summary, md, csv = _summaries(paper)
    _, old_md, old_csv = _summaries(old_paper)
    assert (md, csv) == (old_md, old_csv)
    assert csv.startswith("method,ablation,fidelity,noise,history_cap,horizon,mode,schedule,scenario,task,")
    assert "Team comparison" not in md and against_team_size(summary) == []
    # two teams: two settings, each its own mean; a team column; the comparison
    summary, md, csv = _summaries(paper + duo)
    assert len(summary.settings) == 2
    by_team = {s[summary_team_index()]: summary.stats[(s, "pack_objects")] for s in summary.settings}
    assert by_team[None]["ts"] == 10 and by_team[f"no_mobile@{NO_MOBILE.digest()}"]["ts"] == 20
    assert by_team[None]["succ"] == 1.0 and by_team[f"no_mobile@{NO_MOBILE.digest()}"]["succ"] == 0.0
    assert csv.startswith("method,ablation,fidelity,noise,history_cap,horizon,mode,schedule,team,scenario,task,")
    assert f",sequential,no_mobile@{NO_MOBILE.digest()},,pack_objects," in csv
    assert "## Team comparison" in md
    assert (
        "| heuristic · ablation none · paper | pack_objects | paper | alice (mobile_manipulator), bob (tabletop_arm), "
        "david (mobile_base) | 2 | 1.00 | 10.0 | 9.0 | 4.0 | 16.0 | 1.00 (1.00 / 0.00) | alice 0.50, bob 0.50, david 0.00 |"
    ) in md
    assert (
        "| heuristic · ablation none · paper | pack_objects | no_mobile | alice (mobile_manipulator), bob (tabletop_arm) "
        "| 2 | 0.00 | 20.0 | 15.0 | 0.0 | 20.0 | 1.00 (1.00 / 0.00) | alice 0.75, bob 0.25 |"
    ) in md
    assert "the team no_mobile@" in md  # why no paper figures stand beside it
    # team sizes 3 and 2: the plot against team size, on the page
    plots = against_team_size(summary)
    assert len(plots) == 1 and "against team size" in plots[0][1]
    assert "against team size" in page(summary, [None] * len(summary.rows), md=md)
    # two teams of one size: the comparison, no plot against size
    same_size = [{**r, "team": "trio", "key": "trio/" + r["key"]} for r in paper]
    summary, md, _ = _summaries(paper + same_size)
    assert "## Team comparison" in md and against_team_size(summary) == []


def summary_team_index() -> int:
    from mhrc.eval.rows import SETTING

    return SETTING.index("team")


# --------------------------------------------------------------------------- a real grid


def test_a_real_grid_of_two_teams(tmp_path: Path) -> None:
    spec = EvalSpec(**TINY, teams=(PAPER_TEAM, NO_MOBILE), trials=1)  # type: ignore[arg-type]
    typed = {r.key: r for r in asyncio.run(evaluate(spec, tmp_path / "ev", workers=1))}
    rows = {k: r.metrics for k, r in typed.items()}
    assert sorted(rows) == ["no_mobile/pack_objects/kitchen/3/0", "pack_objects/kitchen/3/0"]
    paper, duo = rows["pack_objects/kitchen/3/0"], rows["no_mobile/pack_objects/kitchen/3/0"]
    assert (paper.team, paper.team_digest, paper.team_kinds) == ("paper", PAPER_TEAM.digest(), PAPER_KINDS)
    assert (duo.team, duo.team_digest, list(duo.team_kinds)) == ("no_mobile", NO_MOBILE.digest(), ["alice", "bob"])
    for m in rows.values():
        assert (
            m.success and sum(m.moves_per_robot.values()) >= 2 * m.total
        )  # each target picked and placed at least once
        assert m.communication_steps <= m.action_steps and set(m.messages_per_robot) == set(m.robots)
    assert paper.moves_per_robot["david"] == 0  # the scout moves nothing
    out = tmp_path / "ev"
    md = (out / "summary.md").read_text()
    assert "## Team comparison" in md and "| no_mobile | alice (mobile_manipulator), bob (tabletop_arm) |" in md
    assert "against team size" in (out / "summary.html").read_text()
    assert (out / "traces" / "no_mobile_pack_objects_kitchen_3_0.jsonl").exists()
    # a trace older than the team field (the field taken out) scores exactly as the world's record of the paper's
    # team; for no_mobile only the team's name differs (its robots are the paper's without David, so its digest is the
    # ablated paper team's): the paper's metrics never read the team
    for key, r in typed.items():
        lines = [json.loads(line) for line in (out / str(r.trace)).read_text().splitlines() if line.strip()]
        old = [
            {**x, "msg": {k: v for k, v in x["msg"].items() if k != "team"}}
            if isinstance(x.get("msg"), dict) and x["msg"].get("kind") == "episode_started"
            else x
            for x in lines
        ]
        now, before = from_trace(records(lines)).as_dict(), from_trace(records(old)).as_dict()
        changed = {k for k in now if now[k] != before[k]}
        assert changed == (set() if key == "pack_objects/kitchen/3/0" else {"team"}), changed
    # --resume with other teams is another evaluation
    with pytest.raises(ConfigError, match="holds another evaluation: --team was"):
        asyncio.run(evaluate(EvalSpec(**TINY), out, resume=True))  # type: ignore[arg-type]
    assert asyncio.run(evaluate(spec, out, resume=True, workers=1)) == list(typed.values())


# --------------------------------------------------------------------------- protocols: an axis like the team


def test_the_papers_protocol_keeps_its_keys_and_the_others_are_prefixed() -> None:
    spec = EvalSpec(**TINY, teams=(PAPER_TEAM, NO_MOBILE), protocols=("mhrc", "centralized"))  # type: ignore[arg-type]
    jobs = spec.jobs()
    assert (
        [j.key for j in jobs]
        == [
            "pack_objects/kitchen/3/0",
            "no_mobile/pack_objects/kitchen/3/0",
            "@centralized/pack_objects/kitchen/3/0",
            "@centralized/no_mobile/pack_objects/kitchen/3/0",
        ]
        == sorted(spec.keys(), key=[j.key for j in jobs].index)
    )
    assert [j.config.protocol for j in jobs] == ["mhrc", "mhrc", "centralized", "centralized"]
    default = EvalSpec(**TINY).identity()  # type: ignore[arg-type]
    old = EvalIdentity.model_validate({k: v for k, v in default.model_dump().items() if k != "protocols"})
    assert old == default and default.protocols == ("mhrc",)  # a manifest older than the axis ran the paper's
    a = EvalSpec(**TINY, protocols=("mhrc", "leader")).identity()  # type: ignore[arg-type]
    b = EvalSpec(**TINY, protocols=("leader", "mhrc")).identity()  # type: ignore[arg-type]
    assert a == b != default and a.protocols == ("leader", "mhrc")


@pytest.mark.parametrize(
    ("values", "message", "code"),
    [
        ({"protocols": ("nope",)}, "--protocol: unknown protocol 'nope'", None),
        ({"protocols": ("leader", "leader")}, "--protocol: 'leader' is given twice", None),
        ({"protocols": ()}, "--protocol must name at least one protocol", None),
    ],
    ids=["unknown", "twice", "none"],  # no_llm_form: every shipped protocol has one (test_protocols)
)
def test_each_protocol_is_checked_before_anything_starts(
    values: dict[str, Any], message: str, code: str | None
) -> None:
    from mhrc.run.config import ProtocolConfigError

    with pytest.raises(ConfigError) as exc:
        EvalSpec(**TINY, **values).validate()  # type: ignore[arg-type]
    assert message in str(exc.value)
    if code is not None:
        assert isinstance(exc.value, ProtocolConfigError) and exc.value.code == code


def test_the_planner_drives_the_robots_an_ablation_leaves_in() -> None:
    """`--ablation no_mobile` under `centralized`: the planner drives Alice and Bob, the episode's team."""
    EvalSpec(**TINY, protocols=("centralized",), ablation="no_mobile").validate()  # type: ignore[arg-type]


def test_a_bad_protocol_on_the_command_line_is_one_line_and_exit_2(tmp_path: Path) -> None:
    for args, message in (
        (["--protocol", "mhrc,leder"], "unknown protocol 'leder' (did you mean 'leader'?)"),
        (["--protocol", "mhrc,centralized", "--protocol", "mhrc"], "'mhrc' is given twice"),
    ):
        out = subprocess.run(
            [sys.executable, "-m", "mhrc", "eval", "--out", str(tmp_path / "x"), *args],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 2 and message in out.stderr and "Traceback" not in out.stderr, out.stderr
        assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_a_real_grid_of_two_protocols(tmp_path: Path) -> None:
    """One episode under the paper's protocol and the same one under the centralized planner:
    their rows, tables, CSV columns, paired comparison and manifest keep them apart, and the
    paper's row is written as it always was (no protocol column)."""
    spec = EvalSpec(**TINY, protocols=("mhrc", "centralized"))  # type: ignore[arg-type]
    out = tmp_path / "ev"
    typed = {r.key: r for r in asyncio.run(evaluate(spec, out, workers=1))}
    assert sorted(typed) == ["@centralized/pack_objects/kitchen/3/0", "pack_objects/kitchen/3/0"]
    paper, central = typed["pack_objects/kitchen/3/0"], typed["@centralized/pack_objects/kitchen/3/0"]
    assert (paper.settings.protocol, central.settings.protocol) == ("mhrc", "centralized")
    lines = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert sorted(str(x.get("protocol")) for x in lines) == ["None", "centralized"]  # the paper's row: no column
    assert central.metrics.messages == 0 and central.metrics.success  # one planner: nothing is told by message
    assert setting_label(setting_of(central)).endswith(" · protocol centralized")
    assert "protocol" not in setting_label(setting_of(paper))
    md = (out / "summary.md").read_text()
    assert "### heuristic · ablation none · paper · protocol centralized" in md
    assert "the centralized protocol, not the paper's" in md
    paired = [line for line in md.splitlines() if line.startswith("| heuristic · ablation none · paper |")]
    assert len(paired) == 1 and "protocol centralized | 1 | 0 / 0 |" in paired[0]  # the same episode, paired
    csv = (out / "summary.csv").read_text().splitlines()
    assert csv[0].split(",")[csv[0].split(",").index("scenario") + 1] == "protocol"
    assert sorted(line.split(",")[9] for line in csv[1:]) == ["", "centralized"]
    assert read_manifest(out / "eval.json").identity.protocols == ("centralized", "mhrc")
    from mhrc.core.protocol import EpisodeStarted
    from mhrc.core.records import messages, read_records

    assert [m.protocol for m in messages(read_records(out / str(central.trace)), EpisodeStarted)] == ["centralized"]
    with pytest.raises(ConfigError, match="holds another evaluation: --protocol was"):
        asyncio.run(evaluate(EvalSpec(**TINY), out, resume=True))  # type: ignore[arg-type]
    assert asyncio.run(evaluate(spec, out, resume=True, workers=1)) == list(typed.values())


def test_resume_names_the_protocols_that_differ() -> None:
    from mhrc.eval.resume import differences

    before, now = EvalSpec(**TINY), EvalSpec(**TINY, protocols=("mhrc", "leader"))  # type: ignore[arg-type]
    assert differences(before, now, {"protocols"}) == ["--protocol was mhrc, now mhrc,leader"]
    assert differences(before, before, {"protocols"}) == []
