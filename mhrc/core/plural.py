"""A count and its noun, as people write them: "1 episode", "2 episodes" (never "1 episodes" or "worker(s)")."""

from __future__ import annotations

__all__ = ["counted"]


def counted(n: float, noun: str, plural: str | None = None) -> str:
    """`n` and `noun`, singular for exactly 1 (`1 day`, `0.5 days`); `plural` when it is not noun + "s"."""
    return f"{n:g} {noun if n == 1 else plural or noun + 's'}"
