"""An episode's recording made while it runs (`mhrc up --rerun`), with no pass over the trace after.

The live recording is a bus observer (mhrc.run.serve's EventHook), beside the recorder: it subscribes
to `mhrc/<run>/**`, and its callback, on Zenoh's thread, only puts the sample on a bounded queue and
returns: it never blocks. A thread writes the queued samples to a logging process of its own
(mhrc.viewer.rerun.logger), which decodes them and logs them to Rerun: the episode's process spends
no interpreter time on the recording beyond the hand-over (bench/bench_rerun.py measures what it
costs). A sample that finds the queue full is dropped and counted (`LiveStats.dropped`): the queue
holds QUEUE samples, far more than an episode publishes while the logger starts.
"""

from __future__ import annotations

import json
import queue
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

from mhrc.core.bus import Bus, Sample
from mhrc.core.keys import Keys
from mhrc.core.lifeline import child_env
from mhrc.viewer.rerun import Target
from mhrc.viewer.rerun.logger import frame
from mhrc.viewer.rerun.sinks import Viewer, start_viewer

QUEUE = 100_000  # samples waiting to be handed to the logging process
CLOSE_WAIT = 60.0  # s close() waits for the logging process to log what it was given


@dataclass(frozen=True)
class LiveStats:
    """What a live recording saw: samples queued, logged by the logging process, dropped (the queue was full,
    or the logging process was gone), the deepest the queue got; the logging process's warnings."""

    queued: int
    logged: int
    dropped: int
    max_depth: int
    warnings: list[str] = field(default_factory=list)


class LiveRecording:
    """A recording of run `run` fed from the bus. `observe` is the hook to give the runner; `close()` hands
    over what is still queued and waits for the recording to be written (a viewer mhrc started stays up:
    `viewer.stop()`). RuntimeError if the viewer does not start."""

    def __init__(self, target: Target, run: str) -> None:
        self.target, self.run = target, run
        self.viewer: Viewer | None = start_viewer(target)
        sink = ["--file", str(target.path)] if target.path is not None else ["--connect", self._url()]
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "mhrc.viewer.rerun.logger", "--run", run, *sink],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=child_env(),
        )
        self._ready()
        self._queue: queue.Queue[tuple[str, bytes, float, bool] | None] = queue.Queue(QUEUE)
        self._t0 = time.perf_counter()
        self.queued = self.dropped = self.max_depth = 0
        self._writer = threading.Thread(target=self._write, name=f"rerun-{run}", daemon=True)
        self._writer.start()

    def _ready(self) -> None:
        """Wait for the logging process to have imported Rerun and opened the recording: its start then costs
        the episode nothing (on a busy machine, an import beside the world's loop slowed it by a second)."""
        assert self._proc.stdout is not None
        line = self._proc.stdout.readline()  # its first line, or nothing if it died
        if not line.strip().startswith(b"{"):
            self._proc.kill()
            self._proc.wait()
            if self.viewer is not None:
                self.viewer.stop()
            raise RuntimeError(
                f"the recording could not start (the logging process ended with code {self._proc.returncode})"
            )

    def _url(self) -> str:
        assert self.viewer is not None
        return self.viewer.url

    @property
    def address(self) -> str | None:
        """What a person opens: the web viewer's page (serve), the native viewer's URL (spawn); None for a file."""
        return self.viewer.address if self.viewer is not None else None

    def observe(self, bus: Bus, run: str) -> None:
        """The runner's observer hook: subscribe to every key of the run, on Zenoh's thread."""
        bus.subscribe(Keys(run).all, self._on_sample, on_thread=True)

    def _on_sample(self, sample: Sample) -> None:
        if sample.key.endswith("/generating"):
            return  # a long model call's progress: its thought is logged
        try:
            self._queue.put_nowait((sample.key, sample.payload, time.perf_counter() - self._t0, sample.is_put))
        except queue.Full:
            self.dropped += 1
            return
        self.queued += 1
        self.max_depth = max(self.max_depth, self._queue.qsize())

    def _write(self) -> None:
        pipe = self._proc.stdin
        assert pipe is not None
        try:
            while (item := self._queue.get()) is not None:
                pipe.write(frame(*item))
                if self._queue.empty():  # a viewer sees the sample now, not when a buffer fills
                    pipe.flush()
        except (BrokenPipeError, OSError):  # the logging process is gone: what is left is dropped
            while self._queue.get() is not None:
                self.dropped += 1

    def close(self) -> LiveStats:
        """Hand over what is queued, wait for the logging process to write the recording, and say what it saw."""
        self._queue.put(None)
        self._writer.join(CLOSE_WAIT)
        try:  # closes the logging process's stdin (the end of the samples), then reads its line
            out, _ = self._proc.communicate(timeout=CLOSE_WAIT)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            out, _ = self._proc.communicate()
        try:
            said = json.loads(out.decode("utf-8").strip().splitlines()[-1])
        except (ValueError, IndexError):
            said = {"logged": 0, "warnings": [f"the logging process ended with code {self._proc.returncode}"]}
        return LiveStats(self.queued, int(said["logged"]), self.dropped, self.max_depth, list(said["warnings"]))
