"""Traces as an older mhrc wrote them, made from a trace of today, for the readers' tests."""

from __future__ import annotations

import json
from pathlib import Path


def as_version_1(trace: Path, out: Path) -> Path:
    """`trace` as protocol version 1 wrote it: no snapshot events, every message's `v` 1."""
    with out.open("w", encoding="utf-8") as f:
        for text in trace.read_text(encoding="utf-8").splitlines():  # the JSON as written, to rewrite it
            row = json.loads(text)
            msg = row["msg"]
            if isinstance(msg, dict):
                if msg["kind"] == "snapshot":
                    continue
                msg["v"] = 1
            f.write(json.dumps(row) + "\n")
    return out
