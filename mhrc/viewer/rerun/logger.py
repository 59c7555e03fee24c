"""The process that makes a live recording (`python -m mhrc.viewer.rerun.logger`), started by
mhrc.viewer.rerun.live: the episode's process only hands it the bus's samples, so decoding them and
Rerun's logging take no time from the world's loop (a thread would share its interpreter's lock),
and it runs at a lower priority (NICE), so that on a busy machine the episode comes first.

On stdin, one frame a sample: a header (`FRAME`: the key's and payload's lengths, the seconds since
the recording began, put or delete) then the key and the payload as the bus carried them. Each
sample is decoded as the trace would record it (mhrc.core.records) and logged
(mhrc.viewer.rerun.episode). On stdout, one JSON line once its recording is open (`ready`), and one
at the end of stdin, once it has sent the blueprint and closed the recording: the samples logged
and the warnings.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import struct
import sys
from pathlib import Path
from typing import BinaryIO

from mhrc.core.lifeline import die_with_parent
from mhrc.core.protocol import ProtocolError
from mhrc.core.protocol.base import loads
from mhrc.core.records import TraceLineError, decode_row
from mhrc.viewer.rerun.episode import EpisodeLogger
from mhrc.viewer.rerun.sinks import close_stream, open_stream

FRAME = struct.Struct("!IIdB")  # key bytes, payload bytes, t, is_put
NICE = 10  # the logging process's niceness: the episode's processes come first for the CPU


def frame(key: str, payload: bytes, t: float, is_put: bool) -> bytes:
    """One sample as the logger reads it."""
    k = key.encode("utf-8")
    return FRAME.pack(len(k), len(payload), t, is_put) + k + payload


def _read(stream: BinaryIO, n: int) -> bytes | None:
    data = stream.read(n)
    return data if data is not None and len(data) == n else None


def log_frames(stream: BinaryIO, logger: EpisodeLogger) -> int:
    """Log every frame of `stream` until it ends; returns how many were logged."""
    logged = 0
    while (head := _read(stream, FRAME.size)) is not None:
        klen, plen, t, is_put = FRAME.unpack(head)
        key, payload = _read(stream, klen), _read(stream, plen)
        if key is None or payload is None:
            break  # cut short: the parent is gone
        try:
            msg = loads(payload)
        except ProtocolError:
            msg = {"raw": payload.decode("utf-8", "replace")}
        try:
            line = decode_row(
                {"t": t, "key": key.decode("utf-8"), "kind": "put" if is_put else "delete", "msg": msg}, 0
            )
            logger.feed(line)
        except TraceLineError:
            continue
        except Exception as exc:  # a record that cannot be drawn must not end the recording
            logger.warnings.append(f"{key.decode('utf-8', 'replace')}: {type(exc).__name__}: {exc}"[:300])
        logged += 1
    return logged


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--run", required=True)
    ap.add_argument("--file", type=Path, default=None, help="the .rrd to write")
    ap.add_argument("--connect", default=None, help="the viewer's gRPC URL to stream to")
    args = ap.parse_args()
    die_with_parent()
    with contextlib.suppress(OSError, AttributeError):  # not on every platform
        os.nice(NICE)  # the world's loop first: on a busy machine the recording catches up after
    rec = open_stream(args.run, args.file, args.connect)
    logger = EpisodeLogger(rec)
    print(json.dumps({"ready": True}), flush=True)  # imported and open: the episode may start
    try:
        logged = log_frames(sys.stdin.buffer, logger)
        logger.finish()
    finally:
        close_stream(rec)
    print(json.dumps({"logged": logged, "warnings": logger.warnings}), flush=True)


if __name__ == "__main__":
    main()
