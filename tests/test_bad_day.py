"""A bad day for the operator (issue 38): a full disk under the trace, participants' text that
would drive the console, secret files readable by others, a fixed port reused at once, a robot
killed mid-episode, a world paused and resumed.

Every command is a real `mhrc` subprocess in a session of its own (its process group is exactly
it and its children) on loopback. Time bounds are generous hang guards, never assertions."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_faults import HANG, _kill_group, _no_strays

FULL = Path("/dev/full")


def _mhrc(args: list[str], cwd: Path, **kwargs: object) -> subprocess.CompletedProcess[str]:
    """`mhrc ARGS` to its end (killed with its group after HANG s: a hang fails the test, not the suite)."""
    proc = subprocess.Popen([sys.executable, "-m", "mhrc", *args], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)  # type: ignore[call-overload]  # fmt: skip
    try:
        out, err = proc.communicate(timeout=HANG)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        pytest.fail(f"mhrc {' '.join(args)} still ran after {HANG} s")
    _no_strays(proc.pid)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


# --------------------------------------------------------------------------- a full disk


@pytest.mark.slow
@pytest.mark.skipif(not FULL.exists(), reason="needs /dev/full (Linux)")
@pytest.mark.parametrize("processes", [False, True])
def test_a_trace_on_a_full_disk_stops_the_run_in_one_line(processes: bool, tmp_path: Path) -> None:
    """`--trace /dev/full`: every write fails with ENOSPC. The run stops, says so in one line
    naming the path and the cause, exits non-zero and leaves nothing running (it hung forever
    in-process, with a traceback per bus message; under --processes it exited 0)."""
    out = _mhrc(["up", "--insecure", "--trace", str(FULL), *(["--processes"] if processes else [])], tmp_path)
    said = [line for line in out.stderr.splitlines() if line.startswith("mhrc")]
    assert out.returncode != 0, out.stderr[-3000:]
    assert "Traceback" not in out.stderr, out.stderr[-3000:]
    assert len(said) == 1 and str(FULL) in said[0] and "No space left on device" in said[0], out.stderr[-3000:]
    assert "episode" not in out.stdout.split("trace /dev/full", 1)[-1], out.stdout  # no metrics table for a run unrecorded


def _fsize_limit(limit: int) -> None:  # in the child, before exec: files it writes cannot grow past `limit` bytes
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


@pytest.mark.slow
def test_a_trace_that_fills_up_mid_run_is_cut_to_whole_lines_and_marked_incomplete(tmp_path: Path) -> None:
    """A trace that can grow to 40 kB only (RLIMIT_FSIZE: writes past it fail, as on a full
    disk): the run stops mid-episode, the trace keeps whole lines only and ends with an
    `incomplete` line naming the error."""
    trace = tmp_path / "trace.jsonl"
    out = _mhrc(["up", "--insecure", "--trace", str(trace)], tmp_path, preexec_fn=lambda: _fsize_limit(40_000))
    said = [line for line in out.stderr.splitlines() if line.startswith("mhrc")]
    assert out.returncode != 0 and "Traceback" not in out.stderr, out.stderr[-3000:]
    assert len(said) == 1 and str(trace) in said[0] and "File too large" in said[0], out.stderr[-3000:]
    text = trace.read_text()
    assert text.endswith("\n"), text[-300:]
    rows = [json.loads(line) for line in text.splitlines()]
    assert rows[-1]["kind"] == "incomplete" and "File too large" in rows[-1]["msg"]["error"], rows[-1]
    assert not any(r.get("msg", {}) and r["msg"].get("kind") == "episode_done" for r in rows if isinstance(r.get("msg"), dict)), "it ran on"
    assert os.path.getsize(trace) <= 40_000


# --------------------------------------------------------------------------- participants' text on the console

EVIL = ("[/]", "[bold red]x", "\x1b]0;pwned\x07\x1b[2J")


@pytest.mark.slow
@pytest.mark.parametrize("processes", [False, True])
def test_a_participants_text_is_printed_inert(processes: bool, tmp_path: Path) -> None:
    """Alice's model writes markup and terminal escapes into a message and an object name: the console prints them as text (markup shown, control
    characters gone), every line arrives, and the run ends normally. Before: `[/]` raised
    MarkupError on the bus thread (the line lost) and the escapes reached the terminal raw."""
    from mhrc.testing import ScriptedModelServer

    said = " ".join(EVIL)
    script = {"alice": [f"Command: communicate({said}, bob)", "Command: pick([bold red]x)"]}
    with ScriptedModelServer(script) as server:
        out = _mhrc(["up", "--insecure", "--horizon", "4", "--llm", "alice=openai:scripted", "--base-url", server.url,
                     *(["--processes"] if processes else [])], tmp_path, env={**os.environ, "COLUMNS": "250", "OPENAI_API_KEY": "x"})  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    assert "MarkupError" not in out.stderr and "Traceback" not in out.stderr, out.stderr[-3000:]
    for control in ("\x1b", "\x07"):
        assert control not in out.stdout and control not in out.stderr, repr(out.stdout[-2000:])
    lines = out.stdout.splitlines()
    message = [line for line in lines if "alice -> bob:" in line]
    assert message and "[/] [bold red]x ]0;pwned[2J" in message[0], lines  # the markup shown as typed, the escapes' control bytes gone
    assert any("pick([bold_red]x)" in line and "There is no '[bold_red]x'" in line for line in lines), lines  # the parser's name, as typed

