"""The ranges of the values an episode's figures hold (`EpisodeMetrics`, `Diagnostics`, and the
rows of an evaluation directory built from them): a count is a non-negative JSON integer (never a
string, a float or a bool), a rate lies in [0, 1], an amount (seconds, a scale) is finite and
non-negative. A directory may come from someone else, so its rows are read through these."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

MAX_COUNT = 2**31 - 1  # the largest count (steps, objects, seeds, tokens) an evaluation's files may hold

Count = Annotated[int, Field(strict=True, ge=0, le=MAX_COUNT)]
Seed = Annotated[int, Field(strict=True, ge=-MAX_COUNT, le=MAX_COUNT)]
Rate = Annotated[float, Field(strict=True, ge=0.0, le=1.0, allow_inf_nan=False)]
Amount = Annotated[float, Field(strict=True, ge=0.0, allow_inf_nan=False)]
NAME = r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}"  # a task, scene or team as a part of a key (and of a file name)
Name = Annotated[str, Field(pattern=f"^{NAME}$")]
