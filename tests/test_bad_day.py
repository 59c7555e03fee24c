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
from test_faults import HANG, _kill_group, _no_strays
from waits import until_sync

FULL = Path("/dev/full")


def _mhrc(args: list[str], cwd: Path, **kwargs: object) -> subprocess.CompletedProcess[str]:
    """`mhrc ARGS` to its end (killed with its group after HANG s: a hang fails the test, not the suite)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "mhrc", *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        **kwargs,
    )  # type: ignore[call-overload]
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
    in-process, with a traceback per bus message; under --processes it exited 0). In-process the
    run is secured: its credentials go to runs/RUN/credentials, never next to the trace into /dev."""
    dev_credentials = FULL.parent / "credentials"
    had = dev_credentials.exists()
    out = _mhrc(["up", "--trace", str(FULL), *(["--processes", "--insecure"] if processes else [])], tmp_path)
    assert dev_credentials.exists() == had, "credentials written into /dev"
    if not processes:
        assert [p.name for p in (tmp_path / "runs").glob("*/credentials")], list(tmp_path.rglob("*"))
    said = [line for line in out.stderr.splitlines() if line.startswith("mhrc")]
    assert out.returncode != 0, out.stderr[-3000:]
    assert "Traceback" not in out.stderr, out.stderr[-3000:]
    assert len(said) == 1 and str(FULL) in said[0] and "No space left on device" in said[0], out.stderr[-3000:]
    assert "[warning" not in out.stderr, out.stderr[-3000:]  # nor an agent's "world vanished" before it attached
    assert "episode" not in out.stdout.split("trace /dev/full", 1)[-1], (
        out.stdout
    )  # no metrics table for a run unrecorded


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
    assert not any(
        r.get("msg", {}) and r["msg"].get("kind") == "episode_done" for r in rows if isinstance(r.get("msg"), dict)
    ), "it ran on"
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
        out = _mhrc(
            [
                "up",
                "--insecure",
                "--horizon",
                "4",
                "--llm",
                "alice=openai:scripted",
                "--base-url",
                server.url,
                *(["--processes"] if processes else []),
            ],
            tmp_path,
            env={**os.environ, "COLUMNS": "250", "OPENAI_API_KEY": "x"},
        )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "MarkupError" not in out.stderr and "Traceback" not in out.stderr, out.stderr[-3000:]
    for control in ("\x1b", "\x07"):
        assert control not in out.stdout and control not in out.stderr, repr(out.stdout[-2000:])
    lines = out.stdout.splitlines()
    message = [line for line in lines if "alice -> bob:" in line]
    assert message and "[/] [bold red]x ]0;pwned[2J" in message[0], (
        lines
    )  # the markup shown as typed, the escapes' control bytes gone
    assert any("pick([bold_red]x)" in line and "There is no '[bold_red]x'" in line for line in lines), (
        lines
    )  # the parser's name, as typed


# --------------------------------------------------------------------------- secret files others can read


@pytest.mark.parametrize("exposed", ["world.key", "users.txt", "world.json", "folder"])
def test_a_world_whose_secrets_others_can_read_is_refused_with_the_chmod(exposed: str, tmp_path: Path) -> None:
    """`mhrc world` with its key, its user dictionary or its password file readable by others, or
    in a folder others can write: refused before anything listens, naming the file and the chmod
    that fixes it (as ssh refuses a private key others can read). It ran without a word before."""
    from mhrc.core.endpoints import free_port

    made = _mhrc(["credentials", "--out", "creds", "--days", "1"], tmp_path)
    assert made.returncode == 0, made.stderr
    creds = tmp_path / "creds"
    target = creds if exposed == "folder" else creds / exposed
    os.chmod(target, 0o777 if exposed == "folder" else 0o644)
    out = _mhrc(
        [
            "world",
            "--port",
            str(free_port()),
            "--credentials",
            str(creds / "world.json"),
            "--start-timeout",
            "1",
            "--quiet",
        ],
        tmp_path,
    )
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    assert "Traceback" not in out.stderr
    fix = f"chmod 700 {creds}" if exposed == "folder" else f"chmod 600 {target}"
    assert str(target) in out.stderr and fix in out.stderr, out.stderr


def test_an_agent_whose_password_file_others_can_read_is_refused(tmp_path: Path) -> None:
    """`mhrc agent --credentials alice.json` with the file 0644: refused with the chmod, before connecting."""
    made = _mhrc(["credentials", "--out", "creds", "--days", "1"], tmp_path)
    assert made.returncode == 0, made.stderr
    alice = tmp_path / "creds" / "alice.json"
    os.chmod(alice, 0o644)
    out = _mhrc(
        [
            "agent",
            "--robot",
            "alice",
            "--connect",
            "tls/127.0.0.1:9",
            "--credentials",
            str(alice),
            "--attach-timeout",
            "1",
        ],
        tmp_path,
    )
    assert out.returncode == 2 and f"chmod 600 {alice}" in out.stderr and "Traceback" not in out.stderr, out.stderr[
        -2000:
    ]


def test_credentials_are_written_0600_in_a_0700_folder_even_over_open_ones(tmp_path: Path) -> None:
    """`mhrc credentials --force` over an open folder and open files, and `mhrc up`'s own: every
    secret 0600 (the CA certificate, public, 0644) in a 0700 folder."""
    import stat

    creds = tmp_path / "creds"
    creds.mkdir(mode=0o777)
    os.chmod(creds, 0o777)
    (creds / "world.key").write_text("old")
    os.chmod(creds / "world.key", 0o666)
    made = _mhrc(["credentials", "--out", "creds", "--days", "1", "--force"], tmp_path)
    assert made.returncode == 0, made.stderr
    up = _mhrc(["up", "--horizon", "1", "--objects", "3", "--quiet"], tmp_path)
    assert up.returncode == 0, up.stderr[-2000:]
    for folder in (creds, *(tmp_path / "runs").glob("*/credentials")):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700, folder
        for f in folder.iterdir():
            assert stat.S_IMODE(f.stat().st_mode) == (0o644 if f.name == "ca.pem" else 0o600), f


@pytest.mark.parametrize("days", ["0.0000001", "0.0006"])
def test_certificates_valid_for_less_than_a_minute_are_refused(days: str, tmp_path: Path) -> None:
    out = _mhrc(["credentials", "--out", "creds", "--days", days], tmp_path)
    assert out.returncode == 2 and "at least a minute" in out.stderr, out.stderr
    assert not (tmp_path / "creds").exists()


# --------------------------------------------------------------------------- a fixed port, at once again


@pytest.mark.slow
@pytest.mark.parametrize("processes", [False, True])
def test_a_fixed_port_can_be_used_again_right_after_a_run(processes: bool, tmp_path: Path) -> None:
    """Two episodes on the same --port, the second started as soon as the first ended: the
    first's connections in TIME_WAIT do not make the port look taken (the pre-check bound
    without SO_REUSEADDR, so for about a minute it said "already in use" while nothing listened)."""
    from mhrc.core.endpoints import free_port

    port = free_port()
    args = [
        "up",
        "--insecure",
        "--port",
        str(port),
        "--objects",
        "3",
        "--horizon",
        "3",
        "--quiet",
        *(["--processes"] if processes else []),
    ]
    for run in ("first", "second"):
        out = _mhrc([*args, "--run", run], tmp_path)
        assert out.returncode == 0, (run, out.stderr[-2000:])
        assert "already in use" not in out.stderr, out.stderr
        if run == "first":
            _time_wait_on(port)  # whether the world or its agents closed their links first: the world's side, for sure


def _time_wait_on(port: int) -> None:
    """Leave a connection in TIME_WAIT on 127.0.0.1:`port` and nothing listening there: the state a
    port is in for a minute after a world that closed its links first."""
    import socket

    with socket.socket() as listener:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", port))
        listener.listen()
        client = socket.create_connection(("127.0.0.1", port))
        conn, _ = listener.accept()
        conn.close()  # the listening side closes first: its socket on `port` goes to TIME_WAIT
        assert client.recv(1) == b""
        client.close()


# --------------------------------------------------------------------------- a robot killed mid-episode


def _child_with(parent: int, needle: str) -> int | None:
    """The pid of a process of `parent`'s group whose command line holds `needle`."""
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            pgid = os.getpgid(int(pid))
        except (OSError, ProcessLookupError):
            continue
        if pgid == parent and needle in cmd and int(pid) != parent:
            return int(pid)
    return None


@pytest.mark.slow
def test_a_robot_killed_mid_episode_is_named_in_the_final_table(tmp_path: Path) -> None:
    """`mhrc up --processes`, Alice's agent killed (SIGKILL) after tick 1 closed: the table says
    she was lost and at which tick (before: only a 'detached ... agent vanished' line mid-run)."""
    import signal

    from test_faults import _start, _until

    proc = _start(["up", "--processes", "--insecure", "--tick-delay", "0.3", "--horizon", "30"], tmp_path)
    try:
        stdout = tmp_path / "stdout.txt"
        _until(lambda: "tick  1 closed" in stdout.read_text(), HANG, "tick 1 closed", proc)
        alice = _child_with(proc.pid, "--robot alice")
        assert alice is not None, "no agent process for alice"
        os.kill(alice, signal.SIGKILL)
        proc.wait(timeout=HANG)
    finally:
        _kill_group(proc)
    out = stdout.read_text()
    table = out[out.index("┌") :] if "┌" in out else ""
    row = [line for line in table.splitlines() if "robots lost" in line]
    assert row and "alice at tick" in row[0] and "vanished" in row[0], out[-3000:]
    tick = int(row[0].split("alice at tick", 1)[1].split()[0])
    assert tick >= 1


# --------------------------------------------------------------------------- a paused world


@pytest.mark.slow
def test_a_world_paused_until_its_agents_give_up_reports_its_own_end(tmp_path: Path) -> None:
    """`mhrc up --processes`, the world stopped (SIGSTOP) after tick 2 until every agent process
    has given up on it, then resumed (SIGCONT): the world ends `no_agents`, and `mhrc up` reports
    that end with its metrics and exit 0. Before: "the world process exited with code 0 before the
    episode ended", exit 1, no metrics (its observer session had lost the world too)."""
    import signal

    from test_faults import _start, _until

    proc = _start(  # agents that give up on a silent world after 5 s instead of the default 30
        ["up", "--processes", "--insecure", "--tick-delay", "0.3", "--horizon", "40", "--attach-timeout", "5"], tmp_path
    )
    stdout = tmp_path / "stdout.txt"
    try:
        _until(lambda: "tick  2 closed" in stdout.read_text(), HANG, "tick 2 closed", proc)
        world = _child_with(proc.pid, "-m mhrc world")
        agents = [_child_with(proc.pid, f"--robot {r}") for r in ("alice", "bob", "david")]
        assert world is not None and None not in agents, (world, agents)
        os.kill(world, signal.SIGSTOP)
        try:
            until_sync(  # the agents give up on a world that does not answer
                lambda: not any(_alive(pid) for pid in agents if pid is not None),
                "the agents giving up on the paused world",
                timeout=HANG,
                every=0.2,
            )
        finally:
            os.kill(world, signal.SIGCONT)
        code = proc.wait(timeout=HANG)
    finally:
        _kill_group(proc)
    out = stdout.read_text()
    err = (tmp_path / "stderr.txt").read_text()
    assert "before the episode ended" not in err, err[-2000:]
    assert code == 0, (code, err[-2000:])
    assert ": no_agents" in out and "partial success" in out and "robots lost" in out, out[-3000:]


def test_the_attach_timeout_reaches_every_agent_and_a_bad_one_is_refused_naming_it() -> None:
    """`mhrc up --processes --attach-timeout S`: every agent process is told S (the paper's command
    lines, at the default, unchanged); a timeout of 0 is refused, naming the option."""
    from mhrc.run.config import ConfigError, EpisodeConfig
    from mhrc.run.processes import agent_command

    cfg = EpisodeConfig.build(attach_timeout=5).resolved()
    for robot in cfg.robots:
        cmd = agent_command(robot, cfg)
        assert cmd[cmd.index("--attach-timeout") + 1] == "5.0"
    assert "--attach-timeout" not in agent_command("alice", EpisodeConfig.build().resolved())
    with pytest.raises(ConfigError, match="^--attach-timeout: Input should be greater than 0"):
        EpisodeConfig.build(attach_timeout=0)


def _alive(pid: int) -> bool:
    """Whether `pid` runs (a zombie, exited but not reaped yet, does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
def test_a_child_that_got_the_terminals_ctrl_c_does_not_warn_about_the_others_leaving(tmp_path: Path) -> None:
    """The terminal's Ctrl-C reaches every process of `mhrc up --processes`; the parent then stops
    the children. When the agents left before the world's own SIGTERM was handled, the world
    warned "robot detached" for each (seen in a full run: three lines beside "interrupted"). Here
    the world alone gets the Ctrl-C, and the agents are killed once it has closed two more ticks
    (a later turn of its loop, so the Ctrl-C was taken): it says nothing of them."""
    import signal

    from test_faults import _start, _until

    trace = tmp_path / "t.jsonl"
    proc = _start(["up", "--processes", "--insecure", "--tick-delay", "0.3", "--trace", str(trace)], tmp_path)

    def ticks() -> int:
        return trace.read_text().count('"kind":"tick"') if trace.exists() else 0

    try:
        _until(lambda: ticks() >= 2, HANG, "two ticks closed", proc)
        world = _child_with(proc.pid, "-m mhrc world")
        agents = [_child_with(proc.pid, f"--robot {r}") for r in ("alice", "bob", "david")]
        assert world is not None and None not in agents, (world, agents)
        os.kill(world, signal.SIGINT)
        after = ticks()
        _until(lambda: ticks() >= after + 2, HANG, "two more ticks closed", proc)
        for pid in agents:
            os.kill(pid, signal.SIGKILL)  # type: ignore[arg-type]
        proc.wait(timeout=HANG)
    finally:
        _kill_group(proc)
    err = (tmp_path / "stderr.txt").read_text()
    assert '"kind":"robot_detached"' in trace.read_text()  # the world saw them leave
    assert "robot detached" not in err, err[-3000:]


def test_hush_quiets_a_logger_bound_before_it(capsys: pytest.CaptureFixture[str]) -> None:
    """structlog fixes a bound logger's level when it is bound (a service binds its run at start):
    a hush afterwards left its warnings on. Errors still show."""
    import structlog

    from mhrc.core import logs

    factory = structlog.get_config()["logger_factory"]  # the session's stderr, not this test's captured one
    try:
        logs.configure("warning")
        bound = structlog.get_logger("mhrc.test").bind(run="r")
        bound.warning("said before the hush")
        logs.hush()
        bound.warning("a participant left")
        bound.error("an error still shows")
        err = capsys.readouterr().err
    finally:
        logs.configure("info")  # tests/conftest.py's
        structlog.configure(logger_factory=factory)
    assert "said before the hush" in err and "an error still shows" in err
    assert "a participant left" not in err
