"""A robot's three histories (feedback, received messages, actions), rendered for its prompt.

Each history prints its older entries, then its newest entry tagged `(latest)`: the paper's
recency tag. Under a character budget the latest entries stay whole; older ones are kept
newest-first while they fit (messages first: a forgotten request costs the most) and the rest
become one summary line per history ("12 earlier entries, steps 0-11, left out: 9 succeeded,
3 failed"), so a 50-step episode's prompt stays within a small model's context.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

HISTORIES = ("feedback", "messages", "actions")
TITLES = {
    "feedback": "Feedback on your actions (oldest first)",
    "messages": "Messages you received (oldest first)",
    "actions": "Your actions so far (oldest first)",
}
LATEST = "(latest)"
SUMMARY_RESERVE = 120  # characters set aside per history for its summary line
MESSAGE_SHARE = 0.5  # older messages may take up to this share of the budget before the rest


@dataclass(frozen=True)
class Entry:
    """One history line. `tag` is what the summary counts when the entry is left out."""

    step: int
    text: str
    tag: str = ""

    def line(self, latest: bool = False) -> str:
        return f"- {LATEST + ' ' if latest else ''}step {self.step}: {self.text}"


@dataclass
class Memory:
    """Feedback, message and action histories, oldest first."""

    feedback: list[Entry] = field(default_factory=list)
    messages: list[Entry] = field(default_factory=list)
    actions: list[Entry] = field(default_factory=list)

    def add(self, history: str, step: int, text: str, tag: str = "") -> None:
        self.history(history).append(Entry(step, text, tag))

    def history(self, name: str) -> list[Entry]:
        if name not in HISTORIES:
            raise ValueError(f"no history {name!r}; histories: {', '.join(HISTORIES)}")
        entries: list[Entry] = getattr(self, name)
        return entries

    def latest(self, name: str) -> list[Entry]:
        """The newest entries: all of the newest step for messages (several can arrive at once)."""
        entries = self.history(name)
        if not entries:
            return []
        if name != "messages":
            return entries[-1:]
        last = entries[-1].step
        n = 0
        while n < len(entries) and entries[-1 - n].step == last:
            n += 1
        return entries[-n:]

    def render(self, names: tuple[str, ...] = HISTORIES, budget: int | None = None) -> dict[str, str]:
        """Each named history as a titled section; `budget` bounds their total characters
        (latest entries excepted, they are always whole)."""
        older = {n: self.history(n)[: len(self.history(n)) - len(self.latest(n))] for n in names}
        keep = {n: len(older[n]) for n in names}  # how many older entries (newest) are kept
        if budget is not None:
            keep = self._fit(names, older, budget)
        return {n: self._section(n, older[n], keep[n]) for n in names}

    def _fit(self, names: tuple[str, ...], older: dict[str, list[Entry]], budget: int) -> dict[str, int]:
        used = sum(len(TITLES[n]) + 2 + sum(len(e.line(True)) + 1 for e in self.latest(n)) for n in names)
        used += SUMMARY_RESERVE * sum(1 for n in names if older[n])
        keep = dict.fromkeys(names, 0)
        closed: set[str] = set()

        def take(name: str, limit: int) -> bool:
            nonlocal used
            if name in closed or keep[name] >= len(older[name]):
                return False
            entry = older[name][-1 - keep[name]]
            cost = len(entry.line()) + 1
            if used + cost > limit:
                closed.add(name)  # kept entries stay a contiguous recent run
                return False
            keep[name] += 1
            used += cost
            return True

        if "messages" in names:
            share = used + int(MESSAGE_SHARE * max(0, budget - used))
            while take("messages", share):
                pass
            closed.discard("messages")
        while True:  # newest first across histories, so all of them reach back about equally
            open_ = [n for n in names if n not in closed and keep[n] < len(older[n])]
            if not open_:
                return keep
            newest = max(open_, key=lambda n: older[n][-1 - keep[n]].step)
            take(newest, budget)

    @staticmethod
    def _summary(left_out: list[Entry]) -> str:
        counts = Counter(e.tag for e in left_out if e.tag)
        what = ", ".join(f"{c} {tag}" for tag, c in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
        n = len(left_out)
        steps = f"step {left_out[0].step}" if n == 1 else f"steps {left_out[0].step}-{left_out[-1].step}"
        return f"- ({n} earlier entr{'y' if n == 1 else 'ies'}, {steps}, left out" + (f": {what})" if what else ")")

    def _section(self, name: str, older: list[Entry], keep: int) -> str:
        lines = [f"{TITLES[name]}:"]
        latest = self.latest(name)
        if not latest:
            return lines[0] + "\n- (none yet)"
        cut = len(older) - keep
        if cut:
            lines.append(self._summary(older[:cut]))
        lines += [e.line() for e in older[cut:]]
        lines += [e.line(latest=True) for e in latest]
        return "\n".join(lines)
