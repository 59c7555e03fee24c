"""A robot's histories (feedback, received messages, actions), rendered with recency tags.

Each history prints its older entries, then its newest one marked "(latest)". A cap on the
characters of all histories keeps the newest entries whole and drops the oldest, saying how
many were dropped, so a 50-step episode's prompt stays within a model's context.
"""

from __future__ import annotations

from dataclasses import dataclass, field

HISTORIES = ("feedback", "messages", "actions")


@dataclass
class Memory:
    cap_chars: int | None = 6000
    feedback: list[str] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)
    actions: list[str] = field(default_factory=list)

    def render(self, name: str) -> str:
        entries: list[str] = getattr(self, name)
        if not entries:
            return "(none yet)"
        budget = None if self.cap_chars is None else max(200, self.cap_chars // len(HISTORIES))
        kept: list[str] = []
        used = 0
        for entry in reversed(entries):  # newest first, always kept whole
            if budget is not None and kept and used + len(entry) > budget:
                break
            kept.append(entry)
            used += len(entry)
        kept.reverse()
        dropped = len(entries) - len(kept)
        lines = [f"({dropped} older entries omitted)"] if dropped else []
        lines += [f"- {e}" for e in kept[:-1]]
        lines.append(f"- {kept[-1]} (latest)")
        return "\n".join(lines)
