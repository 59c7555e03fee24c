"""The world's named colours, each palette once: furniture colours a layout file may name, and
the sort task's colours (a panel and its solids share one; a distractor's has no panel).

Names mean a palette's own colour: a layout's "red" furniture is brick, a sort task's red panel
is signal red, so each palette keeps its own table rather than one table whose names collide.
"""

from __future__ import annotations

from .assets import Color

FURNITURE_COLORS: dict[str, Color] = {
    "wood": (0.55, 0.4, 0.25, 1.0),
    "light": (0.8, 0.75, 0.65, 1.0),
    "white": (0.92, 0.92, 0.9, 1.0),
    "blue": (0.3, 0.35, 0.6, 1.0),
    "green": (0.35, 0.5, 0.35, 1.0),
    "grey": (0.5, 0.5, 0.52, 1.0),
    "red": (0.6, 0.25, 0.2, 1.0),
    "steel": (0.72, 0.74, 0.76, 1.0),
    "dark": (0.22, 0.22, 0.24, 1.0),
    "black": (0.05, 0.05, 0.07, 1.0),
}

PANEL_COLORS: dict[str, Color] = {  # the sort task: one panel per colour, in this order
    "red": (0.85, 0.1, 0.1, 1),
    "blue": (0.1, 0.25, 0.85, 1),
    "pink": (0.95, 0.5, 0.7, 1),
    "green": (0.1, 0.65, 0.2, 1),
    "yellow": (0.95, 0.85, 0.1, 1),
    "purple": (0.5, 0.15, 0.65, 1),
}
NO_PANEL_COLORS: dict[str, Color] = {
    "orange": (0.95, 0.5, 0.05, 1),
    "white": (0.95, 0.95, 0.95, 1),
}  # the sort task's distractors: colours without a panel
