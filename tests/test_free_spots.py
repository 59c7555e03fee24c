"""Where a held object may be set down: the spots clear of every box, computed for the whole grid
of spots at once, are the ones the spot-by-spot check finds."""

from __future__ import annotations

import numpy as np
import pytest

from mhrc.world.skills.manipulation import _clear, _overlaps


@pytest.mark.parametrize("seed", range(5))
def test_clear_spots_are_the_ones_no_box_overlaps(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xs = [round(float(x), 4) for x in np.arange(0.31, 1.2, 0.02)]
    ys = [round(float(y), 4) for y in np.arange(-0.4, 0.4, 0.02)]
    boxes = [
        (
            (float(rng.uniform(0.2, 1.3)), float(rng.uniform(-0.5, 0.5))),
            tuple(float(h) for h in rng.uniform(0.01, 0.1, 2)),
        )
        for _ in range(seed * 2)
    ]
    if seed == 4:  # spots exactly at the edge of a box: the strict comparison decides
        boxes.append(((0.51, 0.0), (0.04, 0.04)))
    half = (0.03, 0.02)
    clear = _clear(xs, ys, half, boxes)  # type: ignore[arg-type]
    want = [[not any(_overlaps((x, y), half, b, h) for b, h in boxes) for y in ys] for x in xs]  # type: ignore[arg-type]
    assert clear == want
    assert seed == 0 or not all(all(row) for row in clear)  # some spots were taken
