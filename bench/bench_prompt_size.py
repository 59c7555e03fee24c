"""Prompt size (characters, estimated tokens) at steps 1, 25 and 50, with and without the cap.

Alice's prompt from a real observation, with histories filled the way a long episode fills
them (one feedback and one action entry per step, a message every fifth step).

    python bench/bench_prompt_size.py [--cap 6000]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from report import emit

from mhrc.agents.llm import ScriptedClient, estimate_tokens
from mhrc.agents.llm_policy import LLMPolicy
from mhrc.world.sim import Sim

FEEDBACK = [
    "navigate(table_1, 0) -> You reached stand pose 0 of table_1. On table_1: apple, book.",
    "pick(apple) -> The end effector could not reach apple: it stayed 0.21 m away (the arm base is 0.92 m from it). Moving your base by dx=0.10, dy=0.25 would bring it within good grasping distance.",
    "place(apple, table_0) -> You placed apple on table_0.",
    "open(drawer_unit) -> You opened drawer_unit. Inside: soap, phone.",
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cap", type=int, default=6000)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    report: dict[str, object] = {"bench": "prompt_size", "robot": "alice", "cap_chars": args.cap}
    with Sim(seed=0, n_objects=6) as sim:
        obs = sim.observe("alice", 0)
        for label, cap in (("capped", args.cap), ("uncapped", None)):
            policy = LLMPolicy("alice", ScriptedClient([]), prompt_cap_chars=cap)
            sizes = {}
            for step in range(1, 51):
                if step in (1, 25, 50):
                    text = "\n\n".join(m["content"] for m in policy.render(obs))
                    sizes[step] = {"chars": len(text), "est_tokens": estimate_tokens(text)}
                policy.memory.feedback.append(f"step {step}: {FEEDBACK[step % len(FEEDBACK)]}")
                policy.memory.actions.append(f"step {step}: {FEEDBACK[step % len(FEEDBACK)].split(' ->')[0]}")
                if step % 5 == 0:
                    policy.memory.messages.append(f"from bob at step {step}: Alice, please bring these to table_0 within my reach: soap, phone.")
            report[label] = sizes
    emit(report, args.out)


if __name__ == "__main__":
    main()
