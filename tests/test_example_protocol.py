"""examples/custom_protocol.py, the runnable example of docs/protocols.md's "Writing a protocol":
it registers a protocol, seats it, plays an episode and its report shows who the robots follow;
its trace passes the observability check (a protocol sees what its robots see, never the world)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mhrc.analysis.observability import check
from mhrc.core.protocol import EpisodeStarted, Thought
from mhrc.core.records import read_records

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "custom_protocol.py"


@pytest.mark.slow
def test_the_example_protocol_registers_runs_and_shows_in_the_report(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, str(EXAMPLE), "--out", str(tmp_path)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "follow_the_finisher: success=True" in done.stdout, done.stdout
    records = read_records(tmp_path / "trace.jsonl")
    started = next(r.msg for r in records if isinstance(r.msg, EpisodeStarted))
    assert started.protocol == "follow_the_finisher"
    leaders = {r.msg.coordination.leader for r in records if isinstance(r.msg, Thought) and r.msg.coordination}
    assert leaders == {"bob"}
    seen = check(records)
    assert seen.unchecked is None and seen.leaks == []
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert "Coordination (follow_the_finisher)" in page and "<th>protocol</th><td>follow_the_finisher</td>" in page
