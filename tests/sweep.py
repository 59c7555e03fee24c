"""A parametrized sweep whose first cases run in the fast tier (`pytest -m "not slow"`) and whose
others run only with the slow tests (CI runs both): one case keeps the behaviour checked on every
run, the sweep checks it everywhere."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import pytest


def sweep(cases: Iterable[Any], fast: int = 1, ids: Iterable[str] | None = None) -> list[Any]:
    """`cases` (a value, or a tuple of values for several argument names) as `pytest.param`s,
    all but the first `fast` marked slow."""
    names = list(ids) if ids is not None else None
    out = []
    for i, case in enumerate(cases):
        values = case if isinstance(case, tuple) else (case,)
        out.append(
            pytest.param(*values, marks=() if i < fast else pytest.mark.slow, id=None if names is None else names[i])
        )
    return out
