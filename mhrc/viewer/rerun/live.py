"""An episode's recording made while it runs (`mhrc up --rerun`), with no pass over the trace after.

The live recording is a bus observer (mhrc.run.serve's EventHook), beside the recorder: it subscribes to
`mhrc/<run>/**` and its callback, on Zenoh's thread, only puts the sample's key and bytes on a bounded
queue and returns (never blocking: the world's loop and the recorder do not wait for Rerun). A thread
of its own decodes each sample as the trace would record it (mhrc.core.records) and logs it
(mhrc.viewer.rerun.episode). A sample that finds the queue full is dropped and counted
(`LiveStats.dropped`): the queue holds QUEUE samples, far more than an episode publishes while the
thread is busy (bench/bench_rerun.py measures both).
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass

from mhrc.core.bus import Bus, Sample
from mhrc.core.keys import Keys
from mhrc.core.protocol import ProtocolError
from mhrc.core.protocol.base import loads
from mhrc.core.records import TraceLineError, decode_row
from mhrc.viewer.rerun import Target
from mhrc.viewer.rerun.episode import EpisodeLogger
from mhrc.viewer.rerun.sinks import Stream, open_stream

QUEUE = 100_000  # samples waiting for the logging thread
CLOSE_WAIT = 30.0  # s close() waits for the thread to log what is queued


@dataclass(frozen=True)
class LiveStats:
    """What a live recording saw: samples queued, logged, dropped (queue full), the deepest the queue got."""

    queued: int
    logged: int
    dropped: int
    max_depth: int
    address: str | None


class LiveRecording:
    """A recording of run `run` fed from the bus. `observe` is the hook to give the runner; `close()`
    logs what is still queued and closes the sink (a viewer mhrc started stays up: `stream.stop_viewer`)."""

    def __init__(self, target: Target, run: str) -> None:
        self.run = run
        self.stream: Stream = open_stream(target, run)
        self._logger = EpisodeLogger(self.stream.rec)
        self._queue: queue.Queue[tuple[str, bool, bytes, float] | None] = queue.Queue(QUEUE)
        self._t0 = time.perf_counter()
        self.queued = self.dropped = self.logged = self.max_depth = 0
        self._thread = threading.Thread(target=self._work, name=f"rerun-{run}", daemon=True)
        self._thread.start()

    @property
    def address(self) -> str | None:
        return self.stream.address

    def observe(self, bus: Bus, run: str) -> None:
        """The runner's observer hook: subscribe to every key of the run, on Zenoh's thread."""
        bus.subscribe(Keys(run).all, self._on_sample, on_thread=True)

    def _on_sample(self, sample: Sample) -> None:
        if sample.key.endswith("/generating"):
            return  # a long model call's progress: its thought is logged
        try:
            self._queue.put_nowait((sample.key, sample.is_put, sample.payload, time.perf_counter() - self._t0))
        except queue.Full:
            self.dropped += 1
            return
        self.queued += 1
        self.max_depth = max(self.max_depth, self._queue.qsize())

    def _work(self) -> None:
        while (item := self._queue.get()) is not None:
            key, is_put, payload, t = item
            try:
                msg = loads(payload)
            except ProtocolError:
                msg = {"raw": payload.decode("utf-8", "replace")}
            try:
                line = decode_row({"t": t, "key": key, "kind": "put" if is_put else "delete", "msg": msg}, 0)
            except TraceLineError:
                continue
            try:
                self._logger.feed(line)
            except Exception as exc:  # a record the logger cannot draw must not stop the recording
                self._logger.warnings.append(f"{key}: {type(exc).__name__}: {exc}"[:300])
            self.logged += 1

    def close(self) -> LiveStats:
        """Log what is queued (up to CLOSE_WAIT seconds), send the blueprint and close the sink."""
        self._queue.put(None)
        self._thread.join(CLOSE_WAIT)
        try:
            self._logger.finish()
        finally:
            self.stream.close()
        return LiveStats(self.queued, self.logged, self.dropped, self.max_depth, self.stream.address)

    @property
    def warnings(self) -> list[str]:
        return list(self._logger.warnings)
