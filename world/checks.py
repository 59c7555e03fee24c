"""An episode's names and sizes checked without building anything: the command lines and the
run's configuration refuse a bad task, scene or object count here, before the simulator is
imported (world/sim.py checks again when it builds)."""

from __future__ import annotations

from .layouts import get_layout
from .tasks import get_task

N_OBJECTS = (3, 6)


def check_episode(*, task: str, scene: str, n_objects: int) -> None:
    """Raise ValueError naming the problem, without building anything."""
    get_task(task)
    get_layout(scene)
    if not N_OBJECTS[0] <= n_objects <= N_OBJECTS[1]:
        raise ValueError(f"n_objects must be between {N_OBJECTS[0]} and {N_OBJECTS[1]}, not {n_objects}")
