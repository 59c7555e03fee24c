"""Where the map's fixed labels go: greedy, collision-checked placement in SVG pixels.

Each label is tried at a list of spots around the thing it names (inside it, then just outside
on each side, then farther out on rings, joined to it by a leader line) and takes the cheapest
spot that overlaps no label already placed and stays on the map. The cost is the spot's rank
plus the area it covers of things better left visible (other furniture, walls, the objects'
resting places), each with a weight. A label that finds no free spot at its size tries a
smaller font. Text boxes are estimated from the characters (a DejaVu Sans-like width per
character, rounded up), since the page is written without a browser to measure it; the
browser test measures the real boxes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

NARROW = set("ilj.,:;'|!()[] ")
HALF = set("ftrI-")
WIDE = set("mwMW@%")
GAP = 2.0  # px kept free around every label


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in SVG pixels (y down)."""

    x0: float
    y0: float
    x1: float
    y1: float

    @classmethod
    def centred(cls, cx: float, cy: float, w: float, h: float) -> Box:
        return cls(cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)

    @property
    def cx(self) -> float:
        return (self.x0 + self.x1) / 2

    @property
    def cy(self) -> float:
        return (self.y0 + self.y1) / 2

    def grow(self, d: float) -> Box:
        return Box(self.x0 - d, self.y0 - d, self.x1 + d, self.y1 + d)

    def overlap(self, other: Box) -> float:
        """The area the two boxes share (0 when they only touch)."""
        w = min(self.x1, other.x1) - max(self.x0, other.x0)
        h = min(self.y1, other.y1) - max(self.y0, other.y0)
        return w * h if w > 0 and h > 0 else 0.0

    def inside(self, other: Box) -> bool:
        return self.x0 >= other.x0 and self.y0 >= other.y0 and self.x1 <= other.x1 and self.y1 <= other.y1

    def clamp(self, x: float, y: float) -> tuple[float, float]:
        """The point of the box nearest (x, y)."""
        return min(max(x, self.x0), self.x1), min(max(y, self.y0), self.y1)


def text_width(text: str, font_px: float) -> float:
    """A generous estimate of the rendered width of `text` in a sans-serif font of `font_px`."""
    em = 0.0
    for ch in text:
        if ord(ch) > 127:
            em += 1.0
        elif ch in NARROW:
            em += 0.34
        elif ch in HALF:
            em += 0.45
        elif ch in WIDE:
            em += 0.98
        elif ch.isupper() or ch.isdigit():
            em += 0.72
        else:
            em += 0.64
    return em * font_px + 2.0


def text_box(cx: float, cy: float, text: str, font_px: float) -> Box:
    """The estimated box of `text` centred on (cx, cy)."""
    return Box.centred(cx, cy, text_width(text, font_px), font_px * 1.25)


@dataclass(frozen=True)
class Request:
    """A label to place: its text, its CSS class and the box of the thing it names."""

    text: str
    cls: str
    anchor: Box
    fonts: tuple[float, ...] = (11.0, 9.0)
    prefer_outside: bool = False


@dataclass(frozen=True)
class Placed:
    """A placed label: its text box, font and the leader line to its anchor (None when it touches it)."""

    request: Request
    box: Box
    font: float
    leader: tuple[float, float, float, float] | None

    @property
    def baseline(self) -> float:
        """The y of the text's baseline that centres it in `box` (SVG text sits on its baseline)."""
        return round(self.box.cy + 0.36 * self.font, 1)


def _spots(a: Box, w: float, h: float, prefer_outside: bool) -> list[tuple[float, float]]:
    aw, ah = a.x1 - a.x0, a.y1 - a.y0
    inside = [(a.cx, a.cy), (a.cx, a.y0 + h / 2 + GAP), (a.cx, a.y1 - h / 2 - GAP)]
    near = [
        (a.cx, a.y1 + h / 2 + GAP),
        (a.cx, a.y0 - h / 2 - GAP),
        (a.x1 + w / 2 + GAP, a.cy),
        (a.x0 - w / 2 - GAP, a.cy),
        (a.x1 - w / 2, a.y1 + h / 2 + GAP),
        (a.x0 + w / 2, a.y1 + h / 2 + GAP),
        (a.x1 - w / 2, a.y0 - h / 2 - GAP),
        (a.x0 + w / 2, a.y0 - h / 2 - GAP),
    ]
    rings = []
    for d in (8.0, 18.0, 30.0, 45.0, 65.0, 90.0):
        for k in range(16):
            t = 2 * math.pi * k / 16 + math.pi / 2  # from straight below, round
            rings.append((a.cx + math.cos(t) * (aw / 2 + w / 2 + d), a.cy + math.sin(t) * (ah / 2 + h / 2 + d)))
    return (near + inside if prefer_outside else inside + near) + rings


def _covered(x0: float, y0: float, x1: float, y1: float, soft: list[tuple[float, float, float, float, float]]) -> float:
    """The weighted area the box (x0, y0, x1, y1) covers of `soft`: Box.overlap times the weight, summed by
    `sum` in the same order, without the boxes it does not overlap (their 0.0 adds nothing)."""
    return sum(
        [
            w * h * weight
            for b0, c0, b1, c1, weight in soft
            if (w := (x1 if x1 < b1 else b1) - (x0 if x0 > b0 else b0)) > 0
            and (h := (y1 if y1 < c1 else c1) - (y0 if y0 > c0 else c0)) > 0
        ]
    )


def place(requests: list[Request], frame: Box, soft: list[tuple[Box, float]]) -> list[Placed]:
    """Place `requests` in order (earlier ones get the better spots) inside `frame`, overlapping
    no placed label; `soft` are (box, weight) things a label should rather not cover."""
    placed: list[Placed] = []
    taken: list[Box] = []  # the placed labels' boxes, grown by GAP
    for req in requests:
        best: tuple[float, Box, float] | None = None
        others = [(b.x0, b.y0, b.x1, b.y1, weight) for b, weight in soft if b != req.anchor]
        for font in req.fonts:
            w, h = text_width(req.text, font), font * 1.25
            for rank, (cx, cy) in enumerate(_spots(req.anchor, w, h, req.prefer_outside)):
                box = Box.centred(cx, cy, w, h)
                if not box.inside(frame) or any(box.overlap(t) for t in taken):
                    continue
                cost = rank * 4.0 + _covered(box.x0, box.y0, box.x1, box.y1, others)
                if best is None or cost < best[0]:
                    best = (cost, box, font)
                if cost == rank * 4.0:
                    break  # nothing covered: later spots only rank worse
            if best is not None and best[2] == font and best[0] < 200:
                break  # a good spot at this size: no need to shrink
        if best is None:  # nowhere free on the map: on the anchor, as before
            font = req.fonts[-1]
            box = text_box(req.anchor.cx, req.anchor.cy, req.text, font)
            best = (0.0, box, font)
        _, box, font = best
        leader = None
        if not box.overlap(req.anchor.grow(3.0)):
            ax, ay = req.anchor.clamp(box.cx, box.cy)
            bx, by = box.clamp(ax, ay)
            leader = (round(ax, 1), round(ay, 1), round(bx, 1), round(by, 1))
        placed.append(Placed(req, box, font, leader))
        taken.append(box.grow(GAP))
    return placed
