"""Traces as an older mhrc wrote them, made from a trace of today, for the readers' tests."""

from __future__ import annotations

import json
from pathlib import Path

from mhrc.core.trace import read_trace


def as_version_1(trace: Path, out: Path) -> Path:
    """`trace` as protocol version 1 wrote it: no snapshot events, every message's `v` 1."""
    with out.open("w", encoding="utf-8") as f:
        for row in read_trace(trace):
            msg = row["msg"]
            if isinstance(msg, dict):
                if msg["kind"] == "snapshot":
                    continue
                msg["v"] = 1
            f.write(json.dumps(row) + "\n")
    return out
