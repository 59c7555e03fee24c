"""A newcomer's first hour (issue 37): nothing lost, nothing paid twice, and no noise. The tests
run the real `mhrc` command (a subprocess where a fresh process matters, click's CliRunner in this
process where only the command's own checks run) on real episodes, real worker processes and real
Zenoh on loopback, and read what a person would see: the lines printed, the exit code, the files
left behind. Also checked elsewhere, on runs those tests make anyway: the per-episode lines of
`mhrc eval` off a terminal (tests/test_eval.py), Ctrl-C on `mhrc up --processes`
(tests/test_faults.py)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import click
import pytest
from click.testing import CliRunner, Result
from waits import until_sync

from mhrc.cli import main
from mhrc.core.endpoints import free_port

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "raw_zenoh_agent.py"
SMALL_EVAL = ["eval", "--tasks", "pack_objects", "--scenes", "kitchen", "--objects", "3,4", "--workers", "1"]


@pytest.fixture(autouse=True)
def _logging_as_the_suite_has_it() -> Iterator[None]:
    """A command run in this process configures logging (--log-level): the next test gets the suite's back."""
    yield
    from mhrc.core import logs

    logs.configure("info")  # tests/conftest.py's


def _mhrc(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """`mhrc ARGS` in a process of its own, as a newcomer runs it: stdout and stderr are pipes."""
    return subprocess.run(
        [sys.executable, "-m", "mhrc", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def _invoke(*args: str) -> Result:
    """`mhrc ARGS` in this process (the current directory is the test's)."""
    return CliRunner().invoke(main, list(args))


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def _errors(result: Result) -> list[str]:
    """A refused option as every option error of mhrc is said (click's usage error): its `Error:` line,
    after the two lines of usage; nothing else."""
    lines = _lines(result.stderr)
    assert len(lines) == 3 and lines[0].startswith("Usage:") and lines[1].startswith("Try "), lines
    return lines[2:]


# --------------------------------------------------------------------------- money and data


def test_resume_on_a_directory_without_an_evaluation_is_one_line_and_creates_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A mistyped --out with --resume used to start (and pay for) the whole grid: now one line, exit 2."""
    monkeypatch.chdir(tmp_path)
    typo = _invoke(*SMALL_EVAL, "--resume", "--out", "runs/nothere")
    assert typo.exit_code == 2 and typo.stdout == "", typo.output
    assert _errors(typo) == [
        "Error: --resume: runs/nothere holds no evaluation (no eval.json); check the path, or leave out "
        "--resume to start one"
    ]
    assert list(tmp_path.iterdir()) == []  # not even runs/
    # a directory holding something else is no evaluation either, and is left as it was
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("buy milk\n")
    other = _invoke(*SMALL_EVAL, "--resume", "--out", "notes")
    assert other.exit_code == 2 and _errors(other) == [
        "Error: --resume: notes holds no evaluation (no eval.json); check the path, or leave out --resume to start one"
    ]
    assert [p.name for p in (tmp_path / "notes").iterdir()] == ["todo.txt"]


def test_eval_with_a_model_server_nobody_runs_fails_at_once_and_creates_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """As `mhrc up` does: a refused connection to the model server is one line before any worker starts."""
    monkeypatch.chdir(tmp_path)
    down = f"http://127.0.0.1:{free_port('127.0.0.1')}/v1"
    out = _invoke(*SMALL_EVAL, "--llm", "openai:x", "--base-url", down, "--out", "ev")
    assert out.exit_code == 2 and out.stdout == "", out.output
    assert _lines(out.stderr) == [
        f"mhrc eval: nothing listens at {down}, the model server of alice, bob, david (connection refused): "
        "start the server there, or point --base-url at one"
    ]
    assert list(tmp_path.iterdir()) == []


def test_evaluate_from_python_checks_what_mhrc_eval_checks(tmp_path: Path) -> None:
    """Issue 44: evaluate() and `mhrc eval` share one pre-flight check (mhrc.eval.engine.preflight):
    a model server nobody runs is refused before DIR is made, not after an episode's retries."""
    import asyncio

    from mhrc.eval.engine import EvalSpec, evaluate
    from mhrc.run.config import ModelServerDown

    down = f"http://127.0.0.1:{free_port('127.0.0.1')}/v1"
    spec = EvalSpec(
        tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), horizon=1, llm="openai:x", base_url=down
    )
    with pytest.raises(ModelServerDown, match=f"nothing listens at {down}, the model server of alice, bob, david"):
        asyncio.run(evaluate(spec, tmp_path / "ev", workers=1))
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def small_eval(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The directory of one real evaluation of two short episodes."""
    where = tmp_path_factory.mktemp("eval")
    done = _mhrc(*SMALL_EVAL, "--horizon", "8", "--out", "ev", cwd=where)
    assert done.returncode == 0, done.stderr[-3000:]
    return where


@pytest.mark.slow
def test_resume_with_other_options_names_the_field_and_both_values_and_show_points_to_report(
    small_eval: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(small_eval)
    rows = (small_eval / "ev" / "episodes.jsonl").read_bytes()
    other = _invoke(*SMALL_EVAL, "--horizon", "14", "--ablation", "no_mobile", "--resume", "--out", "ev")
    assert other.exit_code == 2, other.output
    assert _errors(other) == [
        "Error: --resume: ev holds another evaluation: --ablation was 'none', now 'no_mobile'; --horizon was 8, now 14"
    ]
    assert (small_eval / "ev" / "episodes.jsonl").read_bytes() == rows
    shown = _invoke("show", "ev")  # one episode's command on a directory of many
    assert shown.exit_code == 2 and _lines(shown.stderr) == [
        "mhrc show: ev is an evaluation (mhrc eval), not one episode: `mhrc report ev` summarizes it "
        "(ev/summary.html links every episode's report); each episode's trace and report are in ev/traces/"
    ]
    summary = (small_eval / "ev" / "summary.md").read_text()
    assert "2 episodes, 2 valid." in summary and "docs/evaluation.md#metrics" in summary
    assert "which a sum over three robots cannot be" not in summary  # the long AS paragraph lives in the docs


@pytest.mark.slow
def test_the_diagnostics_plots_legend_covers_no_bar(small_eval: Path) -> None:
    """summary.html's diagnostics plot, for real rows and a second setting whose every bar is tall."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from mhrc.eval.html import diagnostics_figure
    from mhrc.eval.records import from_flat

    rows = [json.loads(line) for line in (small_eval / "ev" / "episodes.jsonl").read_text().splitlines()]
    tall = [
        {**r, "method": "openai:other", **{k: 9 for k, v in r.items() if k.startswith("diag_") and isinstance(v, int)}}
        for r in rows
    ]
    fig = diagnostics_figure([from_flat(r) for r in rows + tall])
    FigureCanvasAgg(fig).draw()
    renderer = fig.canvas.get_renderer()
    (ax,) = fig.axes
    legend = ax.get_legend().get_window_extent(renderer)
    bars = [p.get_window_extent(renderer) for p in ax.patches if p.get_height() > 0]
    assert bars and not [b for b in bars if legend.overlaps(b)]


@pytest.mark.slow
def test_the_quick_start_episode_is_solvable_and_a_reused_run_name_never_destroys_its_trace(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The quick start's `mhrc up --run first ...` (the first report a newcomer opens) solves its
    episode, and `--json` names the run and the trace. Run again, it is refused in one line,
    trace, report and credentials untouched; --overwrite replaces the trace and removes the report
    made of the old one. A cut-off episode's report shows no negative excess; --video-size sizes the video."""
    commands = {
        page: re.findall(r"^mhrc up --run first (.*?)\s*$", (ROOT / page).read_text(), re.M)
        for page in ("docs/quickstart.md", "README.md")
    }
    assert commands["docs/quickstart.md"] == commands["README.md"] and len(commands["README.md"]) == 1, commands
    first = _mhrc("up", "--run", "first", *commands["README.md"][0].split(), "--quiet", "--json", cwd=tmp_path)
    assert first.returncode == 0, first.stderr[-3000:]
    got = json.loads(first.stdout)
    assert got["success"] and got["temporal_steps"] >= got["lower_bound"], got
    assert (got["run"], got["trace"], got["reason"]) == ("first", "runs/first/trace.jsonl", "success")
    run = tmp_path / "runs" / "first"
    monkeypatch.chdir(tmp_path)
    assert _invoke("show", "runs/first").exit_code == 0
    kept = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert {run / "trace.jsonl", run / "trace.html"} <= set(kept) and any("credentials" in p.parts for p in kept)
    for command in (["up", "--quiet"], ["world", "--insecure", "--quiet"]):
        again = _invoke(*command, "--run", "first", "--horizon", "3")
        assert again.exit_code == 2 and again.stdout == "", again.output
        assert [line for line in _lines(again.stderr) if not line.startswith("insecure:")] == [
            f"mhrc {command[0]}: --run first: runs/first/trace.jsonl holds an earlier episode's trace; choose another "
            "--run (or leave it out for a new one), or pass --overwrite to replace it"
        ]
        assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == kept  # nothing rewritten
    replaced = _mhrc(
        *("up", "--run", "first", "--horizon", "2", "--objects", "3", "--quiet", "--overwrite"),
        *("--video", "v.mp4", "--video-size", "160x120"),
        cwd=tmp_path,
    )
    assert replaced.returncode == 0, replaced.stderr[-3000:]
    assert not (run / "trace.html").exists()  # it described the trace that is gone
    assert '"horizon":2,' in (run / "trace.jsonl").read_text()  # the new episode's
    import imageio.v3 as iio

    assert iio.imread(tmp_path / "v.mp4", index=0).shape == (120, 160, 3)
    # horizon 2 is below this episode's bound (cut off before it could finish): no negative excess shown
    assert _invoke("show", "runs/first").exit_code == 0
    report = (run / "trace.html").read_text()
    assert 'data-key="steps_above_bound"' in report and ">n/a<" in report
    assert re.search(r'data-key="steps_above_bound">.*?<td>[^<]*-\d', report) is None


def test_the_video_size_is_checked_and_said_in_help(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert "1280x960 shows the objects clearly" in " ".join(_invoke("show", "--help").stdout.split())
    bad = _invoke("up", "--video", "w.mp4", "--video-size", "big")
    assert bad.exit_code == 2 and "--video-size" in bad.stderr and list(tmp_path.iterdir()) == []


def test_a_bad_replay_trace_is_said_once_and_leaves_no_run_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It used to be reported by each robot's agent (three warnings and a traceback) after
    runs/run-XXXX/ was written."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.jsonl").write_text('{"not": "a trace"}\n')
    out = _invoke("up", "--llm", "replay:bad.jsonl", "--horizon", "3")
    assert out.exit_code == 2 and out.stdout == "", out.output
    assert _lines(out.stderr) == [
        "mhrc up: --llm: alice's replay: bad.jsonl, line 1 is not a trace line (not_a_line): not an object with "
        "a string `key` and a `msg`"
    ]
    assert [p.name for p in tmp_path.iterdir()] == ["bad.jsonl"]


# --------------------------------------------------------------------------- noise


def _episode_started(trace: Path) -> bool:
    return trace.is_file() and re.search(r'"kind": ?"tick"', trace.read_text()) is not None


@pytest.mark.slow
def test_ctrl_c_on_up_is_one_line_naming_the_tick_and_the_trace(tmp_path: Path) -> None:
    """SIGINT to the command's process group, as a terminal's Ctrl-C: it used to warn that every
    robot vanished and print its detach with advice that does not apply; now one line, with the
    tick and the trace (--processes: tests/test_faults.py). The episode's header names its schedule."""
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with out.open("w") as o, err.open("w") as e:
        proc = subprocess.Popen(
            [sys.executable, "-m", "mhrc", "up", "--run", "stopped", "--tick-delay", "0.3", "--insecure"],
            cwd=tmp_path,
            stdout=o,
            stderr=e,
            text=True,
            start_new_session=True,
        )
    trace = tmp_path / "runs" / "stopped" / "trace.jsonl"
    try:
        until_sync(lambda: _episode_started(trace) or proc.poll() is not None, "a tick in the trace", 120)
        assert proc.poll() is None, err.read_text()
        before = len(_lines(err.read_text()))
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    said = _lines(err.read_text())[before:]
    assert proc.returncode == 130 and len(said) == 1, said
    m = re.fullmatch(r"interrupted at tick (\d+), the trace is at runs/stopped/trace\.jsonl", said[0])
    assert m is not None, said
    records = [json.loads(line) for line in trace.read_text().splitlines()]
    closed = [r["msg"]["tick"] for r in records if isinstance(r.get("msg"), dict) and r["msg"].get("kind") == "tick"]
    assert int(m[1]) == max(closed) + 1  # the tick that was running
    printed = out.read_text()
    assert "detached" not in printed and "unless an agent attaches again" not in printed
    assert re.search(
        r"^episode stopped: .*, horizon 50, fidelity paper, lockstep schedule \(every robot plans on the same state; [^)]*\)$",
        printed,
        re.M,
    ), printed


def _block_after(page: Path, marker: str) -> str:
    """The first fenced python block of `page` after the line `marker`."""
    text = page.read_text().split(marker, 1)[1]
    return text.split("```python\n", 1)[1].split("\n```", 1)[0] + "\n"


@pytest.mark.slow
def test_the_outside_pytest_example_prints_only_what_it_prints(tmp_path: Path) -> None:
    """docs/testing.md, "Outside pytest": 30 debug and info lines on stdout used to come first;
    a library prints nothing unless asked (its warnings would go to stderr)."""
    (tmp_path / "example.py").write_text(_block_after(ROOT / "docs" / "testing.md", "## Outside pytest"))
    out = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert re.fullmatch(r"horizon 3 \S+trace\.jsonl\n", out.stdout), out.stdout[-3000:]
    assert out.stderr == ""


def test_the_documented_pytest_command_sets_what_pytest_asyncio_warns_about() -> None:
    """pytest-asyncio 0.24 to 0.26 warn (5 lines, before any test) when the fixtures' loop scope is
    unset; the installed one (1.x) no longer does, so this reads the commands and the pin."""
    page = (ROOT / "docs" / "testing.md").read_text()
    commands = re.findall(r"^# test_\w+\.py: run with `pytest (.*)`$", page, re.M)
    assert len(commands) == 2 and all(
        "-o asyncio_mode=auto" in c and "-o asyncio_default_fixture_loop_scope=function" in c for c in commands
    ), commands
    assert '"pytest-asyncio>=0.24"' in (ROOT / "pyproject.toml").read_text()  # the first that knows the option


def test_the_example_agent_without_a_world_says_so_in_two_lines(tmp_path: Path) -> None:
    """No traceback: what it waits for, for how long, then one error line (and a secured endpoint
    without credentials is refused before anything). `mhrc agent` says the same first line."""
    nobody = f"tcp/127.0.0.1:{free_port('127.0.0.1')}"
    args = ["--run", "x", "--robot", "david", "--attach-timeout", "1"]
    out = subprocess.run(
        [sys.executable, str(EXAMPLE), "--connect", nobody, *args], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 1 and out.stdout == "", out.stderr
    assert _lines(out.stderr) == [
        f"waiting for the world at {nobody} (up to 1 s)",
        f"error: cannot connect to {nobody} within 1 s",
    ]
    tls = nobody.replace("tcp/", "tls/")
    out = subprocess.run(
        [sys.executable, str(EXAMPLE), "--connect", tls, *args], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 2 and _lines(out.stderr) == [
        f"error: --credentials: {tls} is a secured world; pass this robot's credentials file"
    ]
    agent = _invoke("agent", "--robot", "david", "--connect", nobody, "--attach-timeout", "1", "--insecure")
    assert agent.exit_code != 0 and "Traceback" not in agent.output, agent.output
    assert _lines(agent.stderr)[:2] == [
        "insecure: the open tcp bus (no TLS, no login, no access control)",
        f"waiting for the world at {nobody} (up to 1 s)",
    ], agent.stderr


@pytest.mark.slow
def test_the_example_agent_joins_the_default_secured_external_run(tmp_path: Path) -> None:
    """`mhrc up --external david` (secured by default) and the example, given David's credentials file."""
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with out.open("w") as o, err.open("w") as e:
        up = subprocess.Popen(
            [sys.executable, "-m", "mhrc", "up", "--external", "david", "--run", "ext", "--horizon", "4"],
            cwd=tmp_path,
            stdout=o,
            stderr=e,
            text=True,
            start_new_session=True,
        )
    try:
        until_sync(
            lambda: "attach the external robots with" in out.read_text() or up.poll() is not None, "the hint", 120
        )
        hint = re.search(r"--connect (tls/\S+) --credentials (\S+)", out.read_text())
        assert hint is not None, (out.read_text(), err.read_text())
        david = subprocess.run(
            [sys.executable, str(EXAMPLE), "--connect", hint[1], "--robot", "david", "--credentials", hint[2]],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=240,
        )
        assert david.returncode == 0, david.stderr[-3000:]
        assert "attached david" in david.stdout and "episode_done reason=horizon" in david.stdout, david.stdout
        assert up.wait(timeout=120) == 0, err.read_text()[-3000:]
    finally:
        if up.poll() is None:
            os.killpg(up.pid, signal.SIGKILL)
            up.wait()
    acted = [json.loads(line) for line in (tmp_path / "runs" / "ext" / "trace.jsonl").read_text().splitlines()]
    assert any(r["key"].endswith("/robot/david/action/result") for r in acted)


# --------------------------------------------------------------------------- wording


def test_the_readme_names_every_command_of_mhrc_help() -> None:
    listed = re.search(r"`mhrc --help` lists every command: (.*?)\.\n\n", (ROOT / "README.md").read_text(), re.S)
    assert listed is not None
    assert sorted(re.findall(r"`(\w+)`", listed[1])) == main.list_commands(click.Context(main))


def test_counts_and_settings_read_as_words() -> None:
    """'1 episode', never '1 episodes' or 'episode(s)'; a scenario grid is not labelled as the paper's."""
    from mhrc.core.plural import counted

    assert (counted(1, "day"), counted(0.5, "day"), counted(2, "worker"), counted(1, "worker")) == (
        "1 day",
        "0.5 days",
        "2 workers",
        "1 worker",
    )
    one = _invoke("eval", "--dry-run", "--tasks", "pack_objects", "--scenes", "kitchen", "--objects", "3")
    assert one.exit_code == 0 and one.output.splitlines()[-1] == "1 episode (fidelity paper, sequential schedule)"
    dynamic = _invoke("eval", "--dry-run", "--events", "breakdown", "--tasks", "pack_objects")
    assert dynamic.exit_code == 0, dynamic.output
    assert dynamic.output.splitlines()[-1].endswith(
        "episodes (fidelity paper, sequential schedule, scenario breakdown: not the paper's)"
    )
    assert "How much of the participants' log" in " ".join(_invoke("up", "--help").output.split())


def test_the_benchmarks_pages_tables_have_headers_people_read() -> None:
    """No raw JSON key (`result_ms_p50`) as a column header on docs/benchmarks.md."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hook_bench_newcomer", ROOT / "docs" / "hooks" / "bench.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.heading("result_ms_p50") == "result p50 (ms)" and bench.heading("llm_calls") == "LLM calls"
    headers = []
    for placeholder in bench.PLACEHOLDER.finditer((ROOT / "docs" / "benchmarks.md").read_text()):
        lines = bench.render(placeholder["spec"]).splitlines()
        if len(lines) > 1 and lines[1].startswith("| ---"):
            headers += [cell.strip() for cell in lines[0].strip("|").split("|")]
    assert headers and not [h for h in headers if "_" in h], headers


def test_what_ci_runs_and_the_checks_contributing_lists_are_what_the_pages_say() -> None:
    """README: CI installs the browser and runs the checks before "exactly this line"; docs/contributing.md:
    every check it lists comes with the test extra (no pyflakes nothing installs)."""
    ci = (ROOT / ".ci" / "run").read_text()
    readme = (ROOT / "README.md").read_text()
    assert "install-browser.sh" in ci and "`scripts/install-browser.sh`" in readme
    assert "CI runs exactly this line" not in readme
    page = (ROOT / "docs" / "contributing.md").read_text()
    block = page.split("## Checks", 1)[1].split("```bash\n", 1)[1].split("\n```", 1)[0]
    tools = {line.split()[0] for line in block.splitlines() if line.strip()}
    extra = (ROOT / "pyproject.toml").read_text().split("test = [", 1)[1].split("]\n", 1)[0]
    provides = {"lint-imports": "import-linter", "mypy": "mypy", "ruff": "ruff", "mkdocs": "mkdocs"}
    assert tools <= set(provides) and all(f'"{provides[t]}>=' in extra for t in tools), tools
    assert "pyflakes" not in block or "ruff check" in block
