"""Expert demonstrations for fine-tuning: episodes driven by the built-in heuristic through the
environment (`expert=True`), written as JSON lines of (prompt, command) pairs, one file per robot.

Each line is a `Demonstration`: the robot's system prompt and user prompt (exactly what its LLM
agent would be sent on the bus) and the command the expert gave, with where it came from."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict

from mhrc.core.protocol import EpisodeDone

from .parallel import MhrcParallelEnv


class Demonstration(BaseModel):
    """One step of one robot: the prompts it was given and the expert's command."""

    model_config = ConfigDict(extra="forbid")

    robot: str
    task: str
    scene: str
    seed: int
    tick: int
    system: str
    prompt: str
    command: str


@dataclass(frozen=True)
class Demonstrations:
    """What `write_demonstrations` wrote: a file per robot, and how each episode ended."""

    files: dict[str, Path]
    episodes: dict[int, EpisodeDone]  # seed -> the episode's last event (its reason and metrics)
    lines: int


def write_demonstrations(out_dir: str | Path, seeds: Iterable[int], **options: Any) -> Demonstrations:
    """Run one expert episode per seed (lockstep; `options` as `parallel_env`'s) and append every
    robot's steps to `out_dir/<robot>.jsonl`. An episode the expert does not finish is written
    too: its metrics say so (filter on them before training)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    env = MhrcParallelEnv(expert=True, **options)
    cfg = env.core.cfg
    files = {robot: out / f"{robot}.jsonl" for robot in env.possible_agents}
    handles = {robot: path.open("a", encoding="utf-8") for robot, path in files.items()}
    episodes: dict[int, EpisodeDone] = {}
    lines = 0
    try:
        for seed in seeds:
            observations, infos = env.reset(seed=seed)
            system = {robot: info["system_prompt"] for robot, info in infos.items()}
            while env.agents:
                commands = {robot: infos[robot]["expert_action"] for robot in env.agents}
                for robot, command in commands.items():
                    line = Demonstration(
                        robot=robot,
                        task=cfg.task,
                        scene=cfg.scene,
                        seed=seed,
                        tick=infos[robot]["tick"],
                        system=system[robot],
                        prompt=observations[robot]["text"],
                        command=command,
                    )
                    handles[robot].write(line.model_dump_json() + "\n")
                    lines += 1
                observations, _, _, _, infos = env.step(commands)
            assert env.core.done is not None  # no agent is left only when the episode is over
            episodes[seed] = env.core.done
    finally:
        for handle in handles.values():
            handle.close()
        env.close()
    return Demonstrations(files, episodes, lines)
