"""mhrc.env: the world as a PettingZoo environment. PettingZoo's own API and seed tests for every
task, random commands that never raise, the expert solving every task through the env, and the
same actions through `mhrc up`'s bus and through the env giving the same episode."""

from __future__ import annotations

import asyncio
import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test, seed_test

import mhrc.env as mhrc_env
from mhrc.agents.parse import parse_command
from mhrc.core.protocol import (
    ActionResult,
    EpisodeDone,
    Message,
    Observation,
    ScenarioEvent,
    Snapshot,
    TickClosed,
)
from mhrc.core.records import messages, read_records
from mhrc.env import Demonstration, write_demonstrations
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.world.tasks import TASKS

# PettingZoo's tests reset often: short episodes; with the expert, so that its infos are checked too
SMALL: dict[str, Any] = {"objects": 3, "horizon": 2, "expert": True}
FAST_TASK = "pack_objects"  # the fast tier's; the slow tier runs every task
TASK_PARAMS = [pytest.param(t, marks=[] if t == FAST_TASK else [pytest.mark.slow]) for t in TASKS]


@pytest.mark.parametrize("task", TASK_PARAMS)
def test_pettingzoo_api_tests_pass(task: str) -> None:
    api_test(mhrc_env.env(task=task, **SMALL), num_cycles=10)
    parallel_api_test(mhrc_env.parallel_env(task=task, **SMALL), num_cycles=10)


def test_the_spaces_print_in_one_short_line() -> None:
    """gymnasium's Text repr lists its whole charset: `print(env.action_space("alice"))` was
    63,000 characters and the observation space 127,000. They name the charset instead."""
    env = mhrc_env.env(**SMALL)
    try:
        for shown in (str(env.action_space("alice")), repr(env.observation_space("alice"))):
            assert len(shown) < 200 and "\n" not in shown, shown[:300]
        assert str(env.action_space("alice")) == "Text(0, 4200, charset=BMP printable (63,424 characters))"
        assert env.action_space("alice") == env.action_space("bob")  # equality is still gymnasium's
    finally:
        env.close()


@pytest.mark.parametrize("task", [pytest.param(t, marks=[pytest.mark.slow]) for t in TASKS])
def test_pettingzoo_seed_tests_pass(task: str) -> None:
    seed_test(lambda: mhrc_env.env(task=task, **SMALL), num_cycles=10)
    parallel_seed_test(lambda: mhrc_env.parallel_env(task=task, **SMALL), num_cycles=10)


# --------------------------------------------------------------------------- the expert


@pytest.mark.parametrize("task", TASK_PARAMS)
def test_the_expert_solves_every_task_through_the_env_and_its_steps_are_demonstrations(
    task: str, tmp_path: Path
) -> None:
    """The heuristic's commands, given back to the parallel env as strings, solve the task; every
    step is a line of its robot's file: the prompt the robot was shown and a command that parses."""
    written = write_demonstrations(tmp_path, seeds=[1], task=task, objects=3)
    done = written.episodes[1]
    assert done.reason == "success" and done.metrics.success and done.metrics.placed == 3
    assert set(written.files) == {"alice", "bob", "david"}
    lines = [
        Demonstration.model_validate_json(line) for f in written.files.values() for line in f.read_text().splitlines()
    ]
    assert len(lines) == written.lines == 3 * done.metrics.temporal_steps  # every robot, every tick
    for line in lines:
        parse_command(line.command)  # raises on a command the robot's parser cannot read
        assert line.task == task and "Your actions so far" in line.prompt and line.system.startswith("You are")
    assert any(line.command.startswith("communicate(") for line in lines)


@pytest.mark.slow
def test_another_team_and_a_scenario_play_through_the_env() -> None:
    """`mhrc up`'s --team and --events: the agents are the team's robots (a drone among them), the
    scenario's event fires in the world, and the expert still finishes."""
    env = mhrc_env.parallel_env(
        objects=3, expert=True, team="drone_scout", events=Path(__file__).parents[1] / "world/scenarios/close.json"
    )
    observations, infos = env.reset(seed=0)
    assert env.possible_agents == ["alice", "bob", "lucy"]
    assert Observation.model_validate_json(observations["lucy"]["structured"]).status.kind == "drone"
    while env.agents:
        observations, _, _, _, infos = env.step({a: infos[a]["expert_action"] for a in env.agents})
    assert infos["lucy"]["reason"] == "success"
    (event,) = [e for e in env.core.events if isinstance(e, ScenarioEvent)]
    assert event.applied and event.event == "close"
    env.close()


# --------------------------------------------------------------------------- random and bad input


def _vocabulary(obs: dict[str, str], rng: random.Random) -> str:
    """A command of the robot's scene graph's words, often wrong: a random skill, names that exist
    or not, stand poses and distances out of range, messages to nobody."""
    seen = Observation.model_validate_json(obs["structured"]) if obs["structured"] else None
    names = ["fridge", "nowhere", "tray", "david"]
    if seen is not None:
        names += [f.name for f in seen.furniture] + [o.name for o in seen.objects]
    a, b = rng.choice(names), rng.choice(names)
    return rng.choice(
        [
            f"navigate({a}, {rng.randint(-1, 4)})",
            f"move({rng.uniform(-9, 9):.2f}, {rng.uniform(-9, 9):.2f})",
            f"open({a})",
            f"pick({a})",
            f"place({a}, {b})",
            f"communicate(where is the {a}?, {rng.choice(['alice', 'bob', 'david', 'carol'])})",
            "wait()",
            f"pick({a}, {b})",
            "Command: ",
        ]
    )


@pytest.mark.slow
def test_random_commands_for_200_steps_never_raise() -> None:
    """200 turns of the sequential loop, each command sampled from the action space or made of the
    scene's words: every one is its robot's feedback (unreadable, or the skill's failure)."""
    env = mhrc_env.env(objects=3, horizon=100)
    rng = random.Random(7)
    env.reset(seed=4)
    for space_seed, agent in enumerate(env.agents):
        env.action_space(agent).seed(space_seed)
    unreadable, failed = 0, 0
    for step, agent in enumerate(env.agent_iter(200)):
        observation, _, terminated, truncated, info = env.last()
        assert not (terminated or truncated)
        assert env.observation_space(agent).contains(observation)
        unreadable += "unreadable" in info
        failed += "outcome" in info and not info["outcome"]["succeeded"]
        sampled = env.action_space(agent).sample() if rng.random() < 0.5 else None
        env.step(sampled if sampled is not None else _vocabulary(observation, rng))
    assert step == 199
    assert unreadable > 50 and failed > 20  # both kinds of bad command were tried, and told
    env.close()


@pytest.mark.parametrize(
    "option, value, named",
    [
        ("task", "juggle", "juggle"),
        ("scene", "moon", "moon"),
        ("team", "nobody", "nobody"),
        ("objects", 9, "--objects"),
        ("colour", "red", "colour"),
        ("aids", ("x_ray",), "x_ray"),
        ("events", 5, "--events"),  # not a path: said, where it was a TypeError from Path(5)
    ],
)
def test_a_bad_option_is_a_value_error_naming_it_when_the_env_is_made(option: str, value: Any, named: str) -> None:
    for make in (mhrc_env.env, mhrc_env.parallel_env):
        with pytest.raises(ValueError, match=named):
            make(**{option: value})
    with pytest.raises(ValueError, match="render_mode"):
        mhrc_env.parallel_env(render_mode="human")


def test_actions_for_agents_that_are_not_live_or_a_malformed_dict_change_nothing() -> None:
    """Parallel: a ValueError naming the agents, nothing run, the next good step goes on. AEC:
    PettingZoo's rule, a dead agent's only action is None."""
    env = mhrc_env.parallel_env(objects=3, horizon=2)
    env.reset(seed=0)
    wait = dict.fromkeys(env.agents, "wait()")
    for bad, named in (
        ([("alice", "wait()")], "dict"),
        (wait | {"carol": "wait()"}, "carol"),
        ({"alice": "wait()"}, "no action for bob, david"),
    ):
        with pytest.raises(ValueError, match=named):
            env.step(bad)  # type: ignore[arg-type]
    assert env.core.events[-1].kind == "snapshot" and env.core.done is None  # nothing ran
    env.step(wait)
    _, _, _, truncated, infos = env.step(wait)
    assert all(truncated.values()) and infos["bob"]["reason"] == "horizon" and not env.agents
    with pytest.raises(ValueError, match="not live: alice"):
        env.step({"alice": "wait()"})
    assert env.step({}) == ({}, {}, {}, {}, {})
    env.close()

    aec = mhrc_env.env(objects=3, horizon=1)
    aec.reset(seed=0)
    for _ in aec.possible_agents:
        aec.step("wait()")
    assert all(aec.truncations.values())
    with pytest.raises(ValueError, match="None"):
        aec.step("wait()")
    while aec.agents:
        aec.step(None)
    aec.close()


def test_the_rgb_frame_is_the_videos_and_an_unreadable_command_is_feedback() -> None:
    env = mhrc_env.parallel_env(objects=3, horizon=3, render_mode="rgb_array")
    observations, infos = env.reset(seed=0)
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    assert frame.std() > 10  # a picture, not a blank
    observations, rewards, _, _, infos = env.step({"alice": "jump()", "bob": "wait()", "david": 42})
    assert infos["alice"]["unreadable"].startswith("no command found") and infos["david"]["unreadable"]
    assert infos["alice"]["outcome"]["action"] == "wait()" and rewards == dict.fromkeys(env.agents, 0.0)
    assert "could not be read" in observations["alice"]["text"]  # the paper's feedback, in the next prompt
    env.close()


# --------------------------------------------------------------------------- the bus and the env


def _world_events(events: list[Message]) -> tuple[list[TickClosed], list[dict[str, Any]], EpisodeDone]:
    ticks = [e for e in events if isinstance(e, TickClosed)]
    snapshots = [e.model_dump(exclude={"goals"}) for e in events if isinstance(e, Snapshot)]  # goal ids differ
    (done,) = [e for e in events if isinstance(e, EpisodeDone)]
    return ticks, snapshots, done


@pytest.mark.slow
@pytest.mark.parametrize("schedule", ["lockstep", "sequential"])
def test_the_same_actions_through_the_bus_and_the_env_give_the_same_episode(schedule: str, tmp_path: Path) -> None:
    """The heuristic team plays over a real loopback Zenoh bus (`mhrc up` in-process); its actions,
    read from the trace, are given to the env (lockstep: parallel_env, sequential: env). Every
    tick's actions and outcomes, every snapshot of the world, each robot's observations (lockstep)
    and the paper's metrics are the same."""
    trace = tmp_path / "trace.jsonl"
    cfg = EpisodeConfig.build(seed=2, n_objects=3, horizon=8, schedule=schedule, trace=trace).resolved()
    asyncio.run(up_in_process(cfg))
    lines = read_records(trace)
    results = messages(lines, ActionResult)
    commands = {(r.tick, r.robot): r.action.call() for r in results}
    bus_ticks, bus_snapshots, bus_done = _world_events(
        [*messages(lines, TickClosed), *messages(lines, Snapshot), *messages(lines, EpisodeDone)]
    )

    seen: dict[tuple[int, str], Observation] = {}
    if schedule == "lockstep":
        par = mhrc_env.parallel_env(seed=2, objects=3, horizon=8)
        _, infos = par.reset()
        while par.agents:
            tick = infos["alice"]["tick"]
            observations, _, _, _, infos = par.step({a: commands[(tick, a)] for a in par.agents})
            seen |= {(tick, a): Observation.model_validate_json(o["structured"]) for a, o in observations.items()}
        core = par.core
    else:
        aec = mhrc_env.env(seed=2, objects=3, horizon=8)
        aec.reset()
        for agent in aec.agent_iter(1000):
            _, _, terminated, truncated, _ = aec.last()
            aec.step(None if terminated or truncated else commands[(aec.core.world.tick, agent)])  # type: ignore[union-attr]
        core = aec.core
    env_ticks, env_snapshots, env_done = _world_events(core.events)
    assert bus_done.reason == env_done.reason
    assert env_ticks == bus_ticks and len(bus_ticks) == bus_done.metrics.temporal_steps
    assert env_snapshots == bus_snapshots
    assert env_done.metrics.model_dump(exclude={"wall_time"}) == bus_done.metrics.model_dump(exclude={"wall_time"})
    if schedule == "lockstep":  # each result's observation is the one the env gave its robot
        assert {(r.tick, r.robot): r.observation for r in results} == seen
    json.dumps(env_done.metrics.model_dump(mode="json"))
