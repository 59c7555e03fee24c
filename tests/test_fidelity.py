"""The paper's fidelity by default, aids only by name, and every episode saying which it ran with."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from test_llm_policy import obs

from mhrc.agents.llm import ScriptedClient
from mhrc.agents.llm_policy import LLMPolicy, load_hints
from mhrc.core.fidelity import AIDS, label, parse_aids
from mhrc.core.protocol import ActionResult, EpisodeStarted, SkillOutcome, Wait
from mhrc.core.records import messages, read_records
from mhrc.run.config import ConfigError, EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.world.kinds import ARM_FORWARD
from mhrc.world.sim import Sim
from mhrc.world.skills import reaching


def test_the_default_is_the_papers_fidelity_and_aids_are_named() -> None:
    cfg = EpisodeConfig.build()
    assert cfg.aids == () and cfg.fidelity == "paper" and cfg.history_cap is None
    assert EpisodeConfig.build(aids="all").aids == tuple(sorted(AIDS))
    assert EpisodeConfig.build(aids="solved_move, goal_map").fidelity == "aids:goal_map,solved_move"
    assert parse_aids("none") == () and label(()) == "paper"
    with pytest.raises(ConfigError, match="--aids: unknown aid 'x-ray'"):
        EpisodeConfig.build(aids="x-ray")


@pytest.mark.parametrize(
    "aids, fidelity", [((), "paper"), (("goal_map", "status_hints"), "aids:goal_map,status_hints")]
)
async def test_every_trace_records_its_fidelity(tmp_path: Path, aids: tuple[str, ...], fidelity: str) -> None:
    cfg = EpisodeConfig.build(seed=1, n_objects=3, horizon=2, aids=aids, trace=tmp_path / "t.jsonl").resolved()
    await up_in_process(cfg)
    started = messages(read_records(cfg.trace), EpisodeStarted)
    assert [(s.fidelity, s.aids) for s in started] == [(fidelity, list(aids))]


def test_bob_is_told_the_goal_of_each_solid_only_with_the_goal_map_aid() -> None:
    with Sim(task="sort_solids", seed=3, n_objects=4) as sim:
        bob = sim.observe("bob", 0)
        assert bob.goals == {} and bob.targets == sim.targets
        assert not any(goal in bob.task_detail for goal in (f"{t} onto" for t in sim.targets))
    with Sim(task="sort_solids", seed=3, n_objects=4, aids=("goal_map",)) as sim:
        assert sim.observe("bob", 0).goals == sim.goals


def test_reach_labels_are_an_aid_of_the_prompt() -> None:
    from mhrc.core.protocol import ObjectView

    apple = ObjectView(name="apple", position=(-3.3, -0.1, 0.74), on="table_0")
    plain = LLMPolicy("bob", ScriptedClient([])).render(obs(robot="bob", objects=[apple]))[1]["content"]
    aided = LLMPolicy("bob", ScriptedClient([]), reach_labels=True).render(obs(robot="bob", objects=[apple]))[1][
        "content"
    ]
    assert "- apple: position (-3.30, -0.10, 0.74)\n" in plain and "reach)" not in plain.split("# Your status")[0]
    assert "- apple: position (-3.30, -0.10, 0.74) (within your reach)" in aided


def test_alices_prompt_gives_the_simulators_real_picking_distances() -> None:
    # the paper's prompt says 1 m or less; the simulator's figures are the prompt_hints aid's
    text = load_hints("alice")
    assert "about 1 m" not in text
    ahead = re.search(r"arm base sits ([0-9.]+) m ahead", text)
    good = re.search(r"object ([0-9.]+) to ([0-9.]+) m \(horizontally\) from your arm base", text)
    assert ahead and good, "the prompt must say where the arm base is and the good picking range"
    assert float(ahead.group(1)) == pytest.approx(ARM_FORWARD)
    assert (float(good.group(1)), float(good.group(2))) == pytest.approx(reaching.IDEAL_PICK)


def test_histories_are_whole_by_default_and_capped_only_on_request() -> None:
    """The paper keeps whole histories; --history-cap bounds them for small-context models."""

    def fill(policy: LLMPolicy) -> str:
        for step in range(60):
            text = f"step {step} waited " + "x" * 250
            policy.record(
                ActionResult(
                    goal_id=f"g{step}",
                    robot="alice",
                    tick=step,
                    action=Wait(),
                    observation=obs(step),
                    outcome=SkillOutcome.fail(code="plan_failed", feedback=text),
                )
            )  # type: ignore[arg-type]
        return "".join(m["content"] for m in policy.render(obs(60)))

    whole = fill(LLMPolicy("alice", ScriptedClient([])))
    assert "step 0 waited" in whole and len(whole) > 15_000
    capped = fill(LLMPolicy("alice", ScriptedClient([]), prompt_cap_chars=8_000))
    assert len(capped) <= 8_000 and "step 0 waited" not in capped and "left out" in capped
