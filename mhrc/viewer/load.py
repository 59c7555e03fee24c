"""Reading a trace for the viewer, robustly: what could be read, and what was wrong.

A trace is JSONL, one bus message a line (mhrc.core.trace). The viewer must render what it can of a
trace cut off mid-line (a run killed while recording), of one from an older protocol version
(version 1: no `snapshot` events) or with a few damaged lines, and refuse, with one sentence,
a file that is no trace at all, or a line whose message does not fit its model (one of a newer protocol
version says so).

Every line is decoded by mhrc.core.records, which brings an older message to today's shape first
(mhrc.core.upgrade, the one upgrade path): the page reads protocol models, never the JSON as written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel

from mhrc.core.protocol import EpisodeDone, EpisodeStarted, Message, Snapshot
from mhrc.core.records import LineError, LineKind, TraceLine, TraceLineError, messages, parse_line

M = TypeVar("M", bound=BaseModel)


class NotATrace(ValueError):
    """A file with no line that reads as a trace line: the message says why."""


class MalformedLine(NotATrace):
    """A trace line whose message names a protocol kind but does not fit its model (a string where a
    number belongs, a list where an object belongs): `line` is its number, the message names it."""

    def __init__(self, path: Path, line: int, problem: str) -> None:
        self.path, self.line, self.problem = path, line, problem
        super().__init__(f"{path}, line {line}: {problem}")


@dataclass
class LoadedTrace:
    """The decoded lines of a trace (mhrc.core.records: older lines upgraded to today's shape, by
    mhrc.core.upgrade), with warnings about what could not be read. The page reads the messages
    that decoded, as their protocol models, and nothing else."""

    path: Path
    records: list[TraceLine]
    warnings: list[str] = field(default_factory=list)
    versions: set[int] = field(default_factory=set)

    def messages(self, model: type[M]) -> list[M]:
        """Every message of type `model` in the trace, in trace order."""
        return messages(self.records, model)

    def first(self, model: type[M]) -> M | None:
        """The trace's first message of type `model`, or None."""
        return next((line.msg for line in self.records if isinstance(line.msg, model)), None)

    def last(self, model: type[M]) -> M | None:
        """The trace's last message of type `model`, or None."""
        found = self.messages(model)
        return found[-1] if found else None


def _not_finite(value: object) -> bool:
    """Whether a value holds NaN or an infinity anywhere (Python's parser reads `NaN` and `Infinity`, and a
    protocol float takes them; the page's JSON.parse would fail on them). Iterative: a deep value is no error."""
    todo = [value]
    while todo:
        v = todo.pop()
        if isinstance(v, float) and not math.isfinite(v):
            return True
        if isinstance(v, dict):
            todo.extend(v.values())
        elif isinstance(v, (list, tuple)):
            todo.extend(v)
    return False


def malformed(line: TraceLine) -> str | None:
    """Why `line` cannot be shown, or None: a message that names a protocol kind must be a `put`
    that decoded into that kind's model (mhrc.core.records), with finite numbers. The page reads
    what decoded, never the JSON as written, so a value of the wrong type cannot reach it."""
    if not math.isfinite(line.t) or (line.msg is not None and _not_finite(line.msg.model_dump())):
        return "a number is NaN or infinite"
    if line.named is None or line.msg is not None:
        return None
    if line.kind is not LineKind.PUT:
        return f"a {line.kind.value} line carries a {line.named} message"
    return f"the {line.named} message does not fit its model: {line.problem}"


def resolve(path: str | Path) -> Path:
    """A trace file, or the trace.jsonl of a run directory."""
    p = Path(path)
    if p.is_dir():
        return p / "trace.jsonl"
    return p


def load_trace(path: str | Path) -> LoadedTrace:
    """Read `path` (a trace file or a run directory) through the typed reader (mhrc.core.records).
    Raises NotATrace (MalformedLine for a line whose message does not fit its model) or OSError."""
    p = resolve(path)
    if not p.exists():
        given = Path(path)
        if (given / "eval.json").is_file():  # an `mhrc eval` directory: one trace per episode, and its own summary
            raise NotATrace(
                f"{given} is an evaluation (mhrc eval), not one episode: `mhrc report {given}` summarizes it "
                f"({given / 'summary.html'} links every episode's report); each episode's trace and report are in "
                f"{given / 'traces'}/"
            )
        raise NotATrace(f"{p} does not exist" + (" (a run directory holds trace.jsonl)" if given.is_dir() else ""))
    raw = p.read_bytes()
    text = raw.decode("utf-8", "replace")
    lines = text.split("\n")
    ends_with_newline = text.endswith("\n")
    records: list[TraceLine] = []
    bad: list[int] = []
    truncated = False
    nonblank = 0
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        nonblank += 1
        last = i == len(lines) - 1 and not ends_with_newline
        try:
            record = parse_line(line, i + 1)
        except TraceLineError as exc:
            if exc.code is LineError.NOT_JSON and last:
                truncated = True
            else:
                bad.append(i + 1)
            continue
        if record.key.startswith("mhrc/"):
            problem = malformed(record)
            if problem is not None:
                raise MalformedLine(p, record.number, problem)
            records.append(record)
        else:
            bad.append(i + 1)
    if not records:
        if nonblank == 0:
            raise NotATrace(f"{p} is empty")
        raise NotATrace(f"{p} is not an mhrc trace: no line is a JSON object with a `key` under mhrc/ and a `msg`")
    warnings = []
    if truncated:
        warnings.append(
            f"the trace is truncated: its last line (line {len(lines)}) was cut off mid-line and is left out"
        )
    if bad:
        shown = ", ".join(str(n) for n in bad[:5]) + (" ..." if len(bad) > 5 else "")
        warnings.append(f"{len(bad)} line(s) are not trace lines and are left out: line {shown}")
    return from_records(p, records, warnings)


def from_records(path: Path, records: list[TraceLine], warnings: list[str] | None = None) -> LoadedTrace:
    """A trace whose lines were decoded already (by `load_trace`, or by a caller that read the file
    once for its own use, as `mhrc eval` does), with the warnings about what it holds."""
    trace = LoadedTrace(path=path, records=records, warnings=list(warnings or ()))
    for line in records:  # the versions the messages recorded (a message without `v` names none)
        if isinstance(line.msg, Message) and "v" in line.msg.model_fields_set:
            trace.versions.add(line.msg.v)
    if not trace.messages(EpisodeStarted):
        trace.warnings.append(
            "the trace has no episode_started event: task, scene and seed are unknown and the house is not drawn"
        )
    if not trace.messages(Snapshot):
        old = f" (protocol version {max(trace.versions)})" if trace.versions and max(trace.versions) < 2 else ""
        trace.warnings.append(
            f"the trace has no snapshot events{old}: the map shows the robots' positions from their own observations "
            "and no objects"
        )
    if not trace.messages(EpisodeDone):
        trace.warnings.append(
            "the trace has no episode_done event: the episode did not finish while recording, no metrics"
        )
    return trace
