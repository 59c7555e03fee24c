"""Scene layouts as data: `scenes/<name>.json` files, validated on load.

A layout is a house: walls, furniture (tables, blocks such as counters, sofas, drawer units),
Bob's table with his arm, and where Alice and David start. `LAYOUTS` holds the built-in ones
by name; `--scene PATH.json` loads any other file. A new layout is a new data file, never a
new code path. Coordinates are metres in the world frame; furniture is axis-aligned.

The file format (every field is checked on load; an error names the file and the field):

    name, description        the layout's id (lower case, digits, _) and one line for `mhrc scenes`
    bounds                   [xmin, xmax, ymin, ymax] of the floor
    walls                    [[centre x, centre y, size x, size y], ...], 1 m high
    bob                      {table: the furniture Bob is mounted on (a table with a place_pose),
                              base: [x, y, z] of his arm base, yaw,
                              goal_area: [cx, cy, sx, sy] on his table where a task's fixtures go
                              (tray, panels, cutting board), all within his reach,
                              near_slots / far_slots: [[x, y], ...] object spots on his table
                              within / beyond his reach}
    starts                   {robot name: [x, y, yaw], ...}: where robots of these names start (a
                              robot a layout does not name starts on free floor chosen from the
                              seed: placement.py)
    furniture                [{name, kind (how robots are told of it), style (table | block | sofa
                              | drawer_unit | chest | cupboard: how it is built), center [x, y], size [sx, sy, top z],
                              color (a name from colors.FURNITURE_COLORS or [r, g, b, a]),
                              stand_poses: [[x, y, yaw] or {side: north|south|east|west, at: the
                              coordinate along that side}, ...],
                              place_pose [x, y] (omit: nothing can be put on it), place_radius,
                              slots: [[x, y], ...] where a task may put objects on top,
                              drawer (drawer_unit only): {axis [dx, dy] it slides out along,
                              travel, inner [width, depth, wall height], floor (z of its floor),
                              slots [[x, y] in the drawer's frame], max_object_height,
                              handle_out (0.045: how far its handle stands out; a tall unit
                              needs more, for the hand coming down onto it to clear its front)},
                              lid (chest only): {axis [dx, dy] its front faces, open_deg (75),
                              floor (z of its inside floor), slots [[x, y] in the chest's frame,
                              x across, y towards the back], max_object_height},
                              door (cupboard only: one cavity behind a side-hinged door):
                              {axis [dx, dy] its front faces, hinge (left | right, for someone
                              facing the front), at (the door's left edge across the front, from
                              the centre), width, open_deg (85, at most 90), floor and ceiling (z of
                              the cavity), slots [[x, y] in the cavity's frame, x across, y towards
                              the back], max_object_height, handle_out (0.1)},
                              facade (block, drawer_unit, chest, cupboard; looks only, nothing collides):
                              {front [dx, dy] the side it faces (a container's is its axis),
                              panels [{at [across, z] (across: to the right of someone facing
                              the front), size [width, height], color, handle: none | left |
                              right | top}, ...]: doors, windows and fascias drawn on the front}},
                              ...]

A stand pose given by side stands STAND_OFFSET from that edge, facing the furniture. Every
piece of furniture has a stand pose (agents read furniture without one as a task fixture).

Bob's slots and goal area are checked against his reach (ARM_REACH from his arm base): near
slots 0.3 m to ARM_REACH - 0.03; far slots beyond FAR_SLOT (1 m: his prompt, as the paper's
appendix, says he picks best within 1 m of him, and where he is, there, is his arm base, so
an object the task puts out of his reach lies farther; beyond any pose his arm has, too); the
goal area at least the sort task's six panels (0.34 x 0.22 m) and the area of a tray that
holds six objects, with its centre region (the panels' centres) 0.3 m to ARM_REACH and its
corners within GOAL_CORNER_REACH (a tray is filled from a corner). Stand poses and starts keep
clear of where a drawer stands when open and of the floor a door sweeps (the square of its
swing's radius beside its hinge), as they keep clear of walls and furniture; a door's sweep
must not cross a wall, other furniture or another open drawer or door. Every layout has at
least MIN_CONTAINERS closed containers a target can hide in.

This module loads layouts; the schema and its checks are in layout_schema.py (a whole layout)
and furniture_schema.py (one piece of furniture), the specs the simulator uses and their floor
geometry in furniture.py.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator, MutableMapping
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from .furniture import CHASSIS_FOOTPRINT, HOME_FOOTPRINT, DrawerSpec, FurnitureSpec, Layout, door_sweep
from .furniture_schema import STAND_OFFSET
from .layout_schema import ARM_REACH, FAR_SLOT, MIN_CONTAINERS, LayoutFile
from .scene_files import SCENES_DIR, scene_files

__all__ = [
    "ARM_REACH",
    "CHASSIS_FOOTPRINT",
    "FAR_SLOT",
    "HOME_FOOTPRINT",
    "LAYOUTS",
    "MIN_CONTAINERS",
    "SCENES_DIR",
    "STAND_OFFSET",
    "DrawerSpec",
    "FurnitureSpec",
    "Layout",
    "LayoutError",
    "door_sweep",
    "get_layout",
    "load_layout",
    "parse_layout",
]


class LayoutError(ValueError):
    """A layout file that cannot be used; the message names the file and the field."""


# --------------------------------------------------------------------------- loading


def parse_layout(data: Any, source: str = "<data>") -> Layout:
    """Validate layout data (a dict from JSON); LayoutError names `source` and the field."""
    try:
        return LayoutFile.model_validate(data).build(source)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"] if not str(p).startswith(("tuple[", "function-after", "StandSide")))
        msg = err["msg"].removeprefix("Value error, ")
        raise LayoutError(f"{source}: {where + ': ' if where else ''}{msg}") from None


def load_layout(path: str | Path) -> Layout:
    """Read and validate one layout file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise LayoutError(f"{path}: no such layout file") from None
    except json.JSONDecodeError as exc:
        raise LayoutError(f"{path}: not valid JSON: {exc}") from None
    return parse_layout(data, str(path))


class BuiltinLayouts(MutableMapping[str, Layout]):
    """The shipped layouts by name (`scenes/<name>.json`, in the files' order), each file read and
    validated the first time its layout is asked for, not when this module is imported: a run
    reads its own scene only, and a name can be checked (`in`, listed) without reading any. A test
    may put a layout of its own in (pytest's monkeypatch.setitem) as in a dict."""

    def __init__(self, directory: Path) -> None:
        self._files: dict[str, Path | None] = dict(scene_files(directory))
        self._loaded: dict[str, Layout] = {}
        self._lock = threading.Lock()  # the world's simulator is built in a thread of its own

    def __getitem__(self, name: str) -> Layout:
        with self._lock:
            if name not in self._loaded:
                path = self._files[name]  # KeyError for a name no file has
                assert path is not None  # a name set without a file is loaded already
                lay = load_layout(path)
                if lay.name != name:
                    raise LayoutError(f"{path}: name: {lay.name!r} must match the file name {name!r}")
                self._loaded[name] = lay
            return self._loaded[name]

    def __setitem__(self, name: str, layout: Layout) -> None:
        with self._lock:
            self._files.setdefault(name, None)
            self._loaded[name] = layout

    def __delitem__(self, name: str) -> None:
        with self._lock:
            del self._files[name]
            self._loaded.pop(name, None)

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._files))

    def __len__(self) -> int:
        return len(self._files)

    def __contains__(self, name: object) -> bool:
        return name in self._files


LAYOUTS = BuiltinLayouts(SCENES_DIR)


def get_layout(name: str) -> Layout:
    """A built-in layout by name, or any layout file by path (ending in .json)."""
    if name.endswith(".json"):
        return load_layout(name)
    try:
        return LAYOUTS[name]
    except KeyError:
        raise ValueError(
            f"unknown scene {name!r}; known scenes: {', '.join(LAYOUTS)} (or a path to a layout .json file)"
        ) from None
