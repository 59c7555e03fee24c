"""The sandwich stack as it lies (world/physics.py `settled_at`): a slice that comes to rest
tilted across a narrow bacon strip, its low edge on the layer below, is on the stack and reads as
its new top; a slice lying flat beside the strip, or on the board beside the stack, is not. Found
by the two_fetchers team (issue 33): the same place of the cheese failed ten times in a row."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from mhrc.world.physics import PhysicalWorld
from mhrc.world.sim import Sim

BELOW = [("bread_slice_1", -3.1402, 0.0705), ("ham", -3.1314, 0.0883), ("bacon", -3.1487, 0.1234)]  # as found


@pytest.fixture(scope="module")
def world() -> Iterator[PhysicalWorld]:
    with Sim(task="make_sandwich", scene="bedroom", seed=0, n_objects=6) as sim:
        w = sim.world
        z = w.surface_top("cutting_board")
        for name, x, y in BELOW:  # the bacon strip lies off the stack's middle, as a release slip left it
            o = w.objects[name]
            w.rest(o, x, y, z)
            o.on = "cutting_board"
            z += o.kind.height
        yield w


def _drop(w: PhysicalWorld, x: float, y: float, surface: float | None = None) -> bool:
    cheese = w.objects["cheese"]
    w.rest(cheese, x, y, (w.surface_top("cutting_board", without=cheese) if surface is None else surface) + 0.005)
    w.settle(cheese)
    return w.settled_at(cheese, "cutting_board")


def test_a_slice_tilted_across_the_strip_is_the_new_top(world: PhysicalWorld) -> None:
    assert _drop(world, -3.125, 0.0897)
    cheese = world.objects["cheese"]
    _, _, centre = world.position(cheese)
    assert cheese.on == "cutting_board" and centre > max(world.position(world.objects[n])[2] for n, _, _ in BELOW)


@pytest.mark.parametrize("y", [0.05, 0.06])
def test_a_slice_flat_beside_the_strip_is_not_on_the_stack(world: PhysicalWorld, y: float) -> None:
    assert not _drop(world, -3.14, y)
    assert world.objects["cheese"].on == "table_0"


def test_a_slice_on_the_board_beside_the_stack_is_not_on_the_stack(world: PhysicalWorld) -> None:
    board = world.fixtures["cutting_board"]
    assert world.fixture_at(-3.02, 0.0) is board  # over the board, clear of the stack
    assert not _drop(world, -3.02, 0.0, surface=world.table_top() + board.thickness)
    assert world.objects["cheese"].on == "table_0"
