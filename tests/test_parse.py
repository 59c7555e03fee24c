from __future__ import annotations

import pytest

from mhrc.agents.parse import ReplyFormatError, parse_command
from mhrc.core.protocol import Communicate, Move, Navigate, Open, Pick, Place, Wait


@pytest.mark.parametrize(
    "reply, action",
    [
        ("**Command:** navigate(table_1, stand pose 0).", Navigate(target="table_1", stand_pose=0)),
        ("Analysis: ...\nReasoning: ...\nCommand: pick('apple')", Pick(obj="apple")),
        ("```\nplace(apple, tray)\n```", Place(obj="apple", location="tray")),
        ("Command: move(-0.25, 0.1)", Move(dx=-0.25, dy=0.1)),
        ("command: open(drawer_unit).", Open(target="drawer_unit")),
        ("Command: wait()", Wait()),
        ("I could pick(apple) but first: **Command:** wait().", Wait()),
        (
            'Command: communicate("Alice, bring me the fork, please.", alice)',
            Communicate(content="Alice, bring me the fork, please.", to="alice"),
        ),
        ("Command: navigate(table 1, 2)", Navigate(target="table_1", stand_pose=2)),
    ],
)
def test_replies_real_models_write(reply: str, action: object) -> None:
    assert parse_command(reply) == action


@pytest.mark.parametrize(
    "reply, reason",
    [
        ("I think we should wait.", "no command"),
        ("pick(apple) then place(apple, tray)", "several commands"),
        ("Command: pick(apple", "not closed"),
        ("Command: place(apple)", "place takes 2"),
        ("Command: move(left, 1)", "dx must be a number"),
    ],
)
def test_ambiguous_or_broken_replies_explain_themselves(reply: str, reason: str) -> None:
    with pytest.raises(ReplyFormatError, match=reason):
        parse_command(reply)


@pytest.mark.parametrize(
    "reply, action",
    [
        # the order the paper's prompts list (Command, Analysis, Reasoning); the analysis names other calls
        (
            "Command: navigate(drawer, stand pose 0)\nAnalysis: ham and soap could be in the drawer or in cabinet 0; "
            "after that I could open(cabinet_0).\nReasoning: the drawer is the nearest unexplored place.",
            Navigate(target="drawer", stand_pose=0),
        ),
        # the order of the paper's example response (Analysis, Reasoning, Command), its trailing period kept
        (
            "Analysis:\nTask Understanding: the fork is in my gripper.\nReasoning: placing it completes one more item.\nCommand: place(fork, tray).",
            Place(obj="fork", location="tray"),
        ),
        (
            "1. Command: pick(apple)\n2. Analysis: it is 0.4 m away, so pick(apple) can work.\n3. Reasoning: Bob needs it.",
            Pick(obj="apple"),
        ),
    ],
)
def test_the_papers_command_analysis_reasoning_format_parses_in_either_order(reply: str, action: object) -> None:
    assert parse_command(reply) == action
