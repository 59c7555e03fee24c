"""The recorder: every message of one run, as JSON lines.

It subscribes to `mhrc/<run>/**` and to the run's liveliness tokens, so it sees every request,
ack, result, message, thought and world event, whichever process sent them. Each line is
`{"t": seconds since recording started, "key": ..., "kind": "put"|"delete"|"alive"|"gone"|"junk",
"msg": the JSON payload}`: copied as it came when it is ASCII on one line (`_copyable`), else
the parsed payload written again by json.dumps, escaped (every line is ASCII); a payload that is not JSON is kept as `{"raw": its first EXCERPT
characters}`. Malformed action requests and thoughts (too long, too deep, out of bounds: docs/protocol.md,
"Limits"; checked before they are parsed whole) and the world's rejections of them are not copied: a `junk` line per key and second holds their count,
bytes, first reason and the first one's start (EXCERPT characters). So are well-formed requests the
world rejects, past the first REJECTIONS_IN_FULL per robot and interval (a robot flooding its own key
must not fill the disk either): the recorder holds each well-formed request until its ack, then
writes both (the request with the time it was seen) or counts both. The world's answer to a
request (its ack, its result) may reach the recorder before the request itself (the world may
handle the request before the recorder's thread is given it): it is held until the request comes,
and the request is written first, with the time of its answer. An agent's `generating`
status (a long model call's progress, for the console) is not recorded: its thought is.

A write that fails (a full disk) stops the recording at once: the recorder keeps the error
(`Recorder.error`, a TraceWriteError), cuts the file back to its last whole line, adds one
`incomplete` line if it can (in place of the last line if it must), tells `on_error` (the world's side stops the run) and writes
nothing more; it never raises on the bus's threads.
"""

from __future__ import annotations

import contextlib
import json
import os
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mhrc.core.bus import Bus, Sample
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionRequest, ProtocolError, Thought, decode
from mhrc.core.protocol.base import MAX_REQUEST_BYTES, Message, loads
from mhrc.core.protocol.thoughts import MAX_THOUGHT_BYTES
from mhrc.core.records import NotCopied

JUNK_INTERVAL = (
    1.0  # s: malformed requests (and the world's rejections of them) go in as one count per key and interval
)
REJECTIONS_IN_FULL = (
    5  # well-formed requests rejected per robot and interval that are copied in full; the rest are counted
)
MAX_HELD = 20_000  # requests awaiting their ack (a flood arrives faster than the world acks); past it the oldest is written at once
EXCERPT = 200  # characters of a malformed request's payload kept in its junk line: enough to see what it was
REQUEST, THOUGHT = ("robot", "action", "request"), ("agent", "thought")  # an agent's keys, robot left out
AGENTS_SAY: dict[tuple[str, ...], tuple[type[Message], int]] = {  # an agent's key, robot left out -> model, byte bound
    REQUEST: (ActionRequest, MAX_REQUEST_BYTES),
    THOUGHT: (Thought, MAX_THOUGHT_BYTES),
}
THOUGHTS_AHEAD = 8  # a robot's thoughts recorded beyond its action requests: an agent thinks once per action
MAX_REQUESTED = (
    100_000  # goal ids of the requests seen, remembered to tell an early ack or result from one of an old request
)


class TraceWriteError(RuntimeError):
    """The trace could not be written (a full disk, an I/O error): the run stops, the trace is incomplete."""

    code = "trace_write_failed"

    def __init__(self, path: Path, cause: OSError) -> None:
        self.path = path
        self.cause = cause
        super().__init__(
            f"cannot write the trace {path}: {cause.strerror or cause}; the run was stopped and the trace is incomplete"
        )


@dataclass
class _Junk:
    """One key's junk in the current interval, as its `junk` line will say it (mhrc.core.records.JunkCount):
    the first sample's reason, code and excerpt, and the count and bytes of them all."""

    reason: str
    code: str | None
    excerpt: str | None
    since: float  # when the interval started
    count: int = 0
    bytes: int = 0

    def line(self) -> dict[str, str | int | None]:
        """The `junk` line's message, its keys in the order the recorder has always written them."""
        out: dict[str, str | int | None] = {
            "count": self.count,
            "bytes": self.bytes,
            "reason": self.reason,
            "code": self.code,
        }
        if self.excerpt is not None:
            out["excerpt"] = self.excerpt
        return out


class Recorder:
    """Writes every sample of `run` to `path` (JSONL, flushed line by line). `on_error` is called
    once, on a bus thread, when a write fails (see TraceWriteError)."""

    def __init__(
        self, bus: Bus, run: str, path: str | Path, on_error: Callable[[TraceWriteError], object] | None = None
    ) -> None:
        self.path = Path(path)
        self.error: TraceWriteError | None = None
        self._on_error = on_error
        self._good = 0  # bytes of whole lines on disk
        self._last = 0  # where the last of them starts
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._keys = Keys(run)
        self._bus = bus
        self._file: IO[str] | None = None
        self._t0 = time.perf_counter()
        self.count = 0
        self._ended = threading.Event()  # an episode_done event is on disk
        self._junk: dict[str, _Junk] = {}  # key -> counts not yet written
        # goal id -> (t, key, the request's JSON text) of a request awaiting its ack
        self._held: dict[str, tuple[float, str, str]] = {}
        self._requested: dict[str, None] = {}  # goal ids whose request was seen (the newest MAX_REQUESTED, in order)
        self._early: dict[
            str, list[tuple[float, Sample, Any, str | None]]
        ] = {}  # goal id -> its ack or result, come before its request
        self._rejected: dict[str, tuple[float, int]] = {}  # ack key -> (interval start, rejections copied in it)
        self._asked: Counter[str] = Counter()  # robot -> its well-formed action requests seen
        self._thought: Counter[str] = Counter()  # robot -> its thoughts recorded
        self._lock = threading.RLock()  # samples arrive on zenoh's threads (the data's and the liveliness')

    def start(self) -> Recorder:
        self._file = self.path.open("w", encoding="utf-8")
        self._t0 = time.perf_counter()
        # on zenoh's threads, not the event loop: the world's final event is on disk even when
        # the loop is being cancelled (a second Ctrl-C, a parent's SIGTERM) or blocked in close()
        self._bus.subscribe(self._keys.all, self._on_sample, on_thread=True)
        self._bus.watch_liveliness(f"{self._keys.base}/alive/**", self._on_liveliness, on_thread=True)
        return self

    def _write(self, key: str, kind: str, msg: Any, t: float | None = None, raw: str | None = None) -> None:
        """One line; `raw`: its `msg` as JSON text already (a payload as it came, `_copyable`, or a
        held request's), written as it is instead of encoding `msg`."""
        stamp = round((time.perf_counter() if t is None else t) - self._t0, 6)
        body = _dumps(msg) if raw is None else raw
        text = f'{{"t":{stamp!r},"key":{json.dumps(key)},"kind":"{kind}","msg":{body}}}\n'
        with self._lock:  # one whole line at a time, whichever thread
            if self._file is None or self._file.closed or self.error is not None:
                return
            try:
                self._file.write(text)
                self._file.flush()
            except OSError as exc:
                self._fail(exc)
                return
            self._last, self._good = self._good, self._good + len(text)  # ASCII: json.dumps escapes, `raw` is
            self.count += 1

    def _fail(self, exc: OSError) -> None:
        """Stop recording after a failed write: keep the error, close the file, cut it back to its
        whole lines, mark it incomplete (best effort: the disk may still be full) and tell `on_error`."""
        self.error = TraceWriteError(self.path, exc)
        file, self._file = self._file, None
        if file is not None:
            try:
                file.close()  # its unwritten buffer fails again: dropped
            except OSError:
                pass
        if self.path.is_file():
            t = round(time.perf_counter() - self._t0, 6)
            mark = json.dumps(
                {"t": t, "key": f"{self._keys.base}/trace", "kind": "incomplete", "msg": {"error": str(exc)}},
                separators=(",", ":"),
            )
            for end in (self._good, self._last):  # the mark in place of the last whole line if it does not fit after it
                try:
                    os.truncate(self.path, end)
                    with self.path.open("a", encoding="utf-8") as f:
                        f.write(mark + "\n")
                    break
                except OSError:
                    with contextlib.suppress(OSError):
                        os.truncate(self.path, end)
        if self._on_error is not None:
            try:
                self._on_error(self.error)
            except Exception:  # a loop already closed: the caller reads self.error
                pass

    def _on_sample(self, sample: Sample) -> None:
        if sample.key.endswith("/generating"):
            return  # an agent's live status of a long model call: its thought records the call
        if sample.is_put and self._is_malformed(sample):
            return  # an agent's request or thought that is none: counted, never parsed whole nor copied
        raw: str | None = None
        try:
            msg: Any = loads(sample.payload)
            raw = _copyable(sample.payload)
        except ProtocolError:
            msg = {"raw": _excerpt(sample.payload)}
        goal = msg.get("goal_id") if isinstance(msg, dict) else None
        with self._lock:
            if (
                sample.is_put
                and isinstance(goal, str)
                and goal in self._early
                and sample.key.endswith("/action/request")
            ):
                early = self._early.pop(goal)
                # seen after its answer, written before it, at the answer's time
                self._record(sample, msg, early[0][0], raw)
                for t, s, m, r in early:
                    self._record(s, m, t, r)
                return
            self._record(sample, msg, None, raw)

    def _record(self, sample: Sample, msg: Any, t: float | None = None, raw: str | None = None) -> None:
        if sample.is_put and (
            self._is_junk(sample, msg)
            or self._thinks_ahead(sample)
            or self._too_early(sample, msg, t, raw)
            or self._held_or_counted(sample, msg, t, raw)
        ):
            return
        self._write(sample.key, "put" if sample.is_put else "delete", msg, t, raw)
        if isinstance(msg, dict) and msg.get("kind") == "episode_done":
            self._ended.set()

    def _thinks_ahead(self, sample: Sample) -> bool:
        """A thought of a robot that has thought more than THOUGHTS_AHEAD times beyond its action
        requests: counted, not copied. An agent publishes one thought per decision and one
        request per decision, so an honest agent never gets there; a login putting well-formed
        thoughts in a loop (each within the bounds, a few MB) would otherwise fill the disk."""
        said = self._said_by(sample.key)
        if said is None:
            return False
        what, robot = said
        if what == REQUEST:
            self._asked[robot] += 1
            return False
        if self._thought[robot] >= self._asked[robot] + THOUGHTS_AHEAD:
            self._count_junk(
                sample.key,
                f"more than {THOUGHTS_AHEAD} thoughts beyond the robot's action requests",
                len(sample.payload),
                time.perf_counter(),
                NotCopied.THOUGHTS_AHEAD.value,
            )
            return True
        self._thought[robot] += 1
        return False

    def _too_early(self, sample: Sample, msg: Any, t: float | None, raw: str | None = None) -> bool:
        """The world's ack or result of a request not seen yet, held until it comes: the world's
        answer reaches the recorder inside its put, and the world may handle the request and
        answer before the agent's link delivers the request to the recorder. True when the sample is held."""
        if not (sample.key.endswith("/action/ack") or sample.key.endswith("/action/result")) or not isinstance(
            msg, dict
        ):
            return False
        goal = msg.get("goal_id")
        if not isinstance(goal, str) or goal in self._requested or goal in self._held:
            return False
        self._early.setdefault(goal, []).append((time.perf_counter() if t is None else t, sample, msg, raw))
        if len(self._early) > MAX_HELD:  # answers to requests that never come: do not hold forever
            for t_old, s, m, r in self._early.pop(next(iter(self._early))):
                self._write(s.key, "put", m, t_old, r)
        return True

    def _said_by(self, key: str) -> tuple[tuple[str, ...], str] | None:
        """For an agent's key of this run (robot/<rid>/action/request, agent/<rid>/thought): the
        key with the robot left out (as AGENTS_SAY holds it) and the robot; None for any other key."""
        below = key.removeprefix(self._keys.base + "/").split("/")
        what = (below[0], *below[2:])
        return (what, below[1]) if len(below) > 2 and what in AGENTS_SAY else None

    def _is_malformed(self, sample: Sample) -> bool:
        """An action request or a thought that is not one (too long, too deep, out of bounds:
        docs/protocol.md, "Limits"): counted, not copied (a flood of junk must not fill the disk).
        Lines of kind `junk` carry, per key and interval, the count, the bytes, the first reason
        and the first one's start."""
        said = self._said_by(sample.key)
        if said is None:
            return False
        model, limit = AGENTS_SAY[said[0]]
        try:
            decode(sample.payload, model, max_bytes=limit)
            return False
        except ProtocolError as exc:
            reason = str(exc)
        with self._lock:
            self._count_junk(
                sample.key, reason, len(sample.payload), time.perf_counter(), "malformed", _excerpt(sample.payload)
            )
        return True

    def _is_junk(self, sample: Sample, msg: Any) -> bool:
        """The world's rejection of a malformed request: counted with the request, not copied."""
        if not (sample.key.endswith("/action/ack") and isinstance(msg, dict) and msg.get("accepted") is False):
            return False
        if msg.get("code") != "malformed":
            return False
        with self._lock:
            self._count_junk(
                sample.key, str(msg.get("reason", "")), len(sample.payload), time.perf_counter(), "malformed"
            )
        return True

    def _held_or_counted(self, sample: Sample, msg: Any, t: float | None = None, raw: str | None = None) -> bool:
        """Hold a well-formed request until its ack; at the ack, write the request then let the
        ack be written, or, for a rejection past REJECTIONS_IN_FULL in this interval, count both
        as junk. True when the sample is held or counted (not to be written now)."""
        if not isinstance(msg, dict) or not isinstance(msg.get("goal_id"), str):
            return False
        now = time.perf_counter() if t is None else t
        with self._lock:
            if sample.key.endswith("/action/request"):
                self._held[msg["goal_id"]] = (now, sample.key, _dumps(msg) if raw is None else raw)
                self._requested[msg["goal_id"]] = None
                if len(self._requested) > MAX_REQUESTED:
                    del self._requested[next(iter(self._requested))]
                if len(self._held) > MAX_HELD:  # acks that never come (a world gone): do not hold forever
                    oldest = next(iter(self._held))
                    t, key, text = self._held.pop(oldest)
                    self._write(key, "put", None, t, text)
                return True
            if not sample.key.endswith("/action/ack"):
                return False
            held = self._held.pop(msg["goal_id"], None)
            if msg.get("accepted") is False:
                start, copied = self._rejected.get(sample.key, (now, 0))
                if now - start >= JUNK_INTERVAL:
                    start, copied = now, 0
                if copied >= REJECTIONS_IN_FULL:
                    reason, code = "rejected: " + str(msg.get("reason", "")), msg.get("code")
                    if held is not None:
                        self._count_junk(held[1], reason, len(held[2]), now, code)
                    self._count_junk(sample.key, reason, len(sample.payload), now, code)
                    return True
                self._rejected[sample.key] = (start, copied + 1)
            if held is not None:
                self._write(held[1], "put", None, held[0], held[2])
            return False

    def _count_junk(
        self, key: str, reason: str, size: int, now: float, code: object = None, excerpt: str | None = None
    ) -> None:
        """Count one junk sample of `key`; `code` is the rejection's (mhrc.core.protocol.RejectCode), if it has one;
        `excerpt`, the start of a malformed payload (the interval's first is kept)."""
        junk = self._junk.get(key)
        if junk is None:
            junk = self._junk[key] = _Junk(reason[:300], code if isinstance(code, str) else None, excerpt, now)
        junk.count += 1
        junk.bytes += size
        if now - junk.since >= JUNK_INTERVAL:
            self._flush_junk(key)

    def _flush_junk(self, key: str) -> None:
        junk = self._junk.pop(key, None)
        if junk is not None and junk.count:
            self._write(key, "junk", junk.line())

    def _on_liveliness(self, sample: Sample) -> None:
        self._write(sample.key, "alive" if sample.is_put else "gone", None)

    def close(self, *, until_done: float = 0.0) -> None:
        """Stop writing; with `until_done`, first wait up to that many seconds for the episode's
        final event, published but maybe still on its way (a blocking wait: a second Ctrl-C or
        SIGTERM cancelling the caller's task cannot cut it short and lose the event)."""
        if until_done > 0:
            self._ended.wait(until_done)
        with self._lock:
            for t, key, text in self._held.values():  # requests never acked (the episode ended first)
                self._write(key, "put", None, t, text)
            self._held.clear()
            for t, s, m, r in sorted((e for early in self._early.values() for e in early), key=lambda e: e[0]):
                self._write(s.key, "put", m, t, r)  # answers whose request never came
            self._early.clear()
            for key in list(self._junk):
                self._flush_junk(key)
        with self._lock:
            if self._file is not None:
                try:
                    self._file.close()
                except OSError as exc:
                    self._fail(exc)


def _excerpt(payload: bytes) -> str:
    """The start of a payload recorded by excerpt (EXCERPT characters)."""
    return payload[: EXCERPT * 4].decode("utf-8", "replace")[:EXCERPT]


def _dumps(msg: Any) -> str:
    """`msg` as a line's JSON text, the way the recorder always wrote it (compact, escaped to ASCII)."""
    return json.dumps(msg, separators=(",", ":"))


def _copyable(payload: bytes) -> str | None:
    """The payload as its line's `msg`, copied as it came, when that is safe: JSON already parsed
    (the caller's), ASCII and without \\n or \\r, so nothing in it ends a line for any reader
    (below 0x20, valid JSON holds only its whitespace unescaped: tab, \\n, \\r; DEL, which
    json.dumps escapes, may stay as it came). None: the recorder writes the parsed value again
    (json.dumps escapes what is not ASCII)."""
    if not payload.isascii() or b"\n" in payload or b"\r" in payload:
        return None
    return payload.decode("ascii")
