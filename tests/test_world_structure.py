"""The world's skill registry: every action the protocol defines runs as exactly one registered
skill (communicate excepted: the world service delivers messages). Import circles and module
sizes are checked for the whole package by tests/test_layers.py."""

from __future__ import annotations

from typing import get_args

from mhrc.core.protocol import Action, Communicate
from mhrc.world.skills import SKILLS


def test_every_action_but_communicate_runs_as_one_registered_skill() -> None:
    actions = set(get_args(get_args(Action)[0]))  # Annotated[Union[...], discriminator]
    assert Communicate in actions and len(actions) > 2
    assert set(SKILLS) == actions - {Communicate}  # communicate is the world service's
