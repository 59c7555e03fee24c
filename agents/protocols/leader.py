"""`leader`: DynaHMRC's loop (to come)."""

from __future__ import annotations

from collections.abc import Mapping

from ..policy import Policy
from .base import Seating


def build_leader(seating: Seating) -> Mapping[str, Policy]:
    raise NotImplementedError
