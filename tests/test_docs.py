"""The docs keep their word: every shell and Python example in README.md and docs/ runs as written,
the site builds with `mkdocs build --strict`, and the benchmark tables come from bench/results/.

Examples run as a reader runs them from the project root: the installed `mhrc` and this Python
first on PATH, in a fresh directory holding links to the checkout's read-only directories,
loopback only (the CLI's defaults), every process the block started ended afterwards. A block
that cannot run here says why in `<!-- not run: REASON -->` right above its fence and is
skipped with that reason; `<!-- slow: REASON -->` puts it in the slow tier. How to write them:
docs/contributing.md, "The docs".
"""

from __future__ import annotations

import importlib.util
import json
import logging
import os
import re
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType, SimpleNamespace

import pytest

from mhrc.core.endpoints import free_port

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
RUNNABLE = {"bash", "sh", "console", "python"}
LINKED = (
    "mhrc",
    "world",
    "agents",
    "prompts",
    "examples",
    "bench",
    "docker",
    "deploy",
)  # what an example may read from the checkout
EXAMPLE_TIMEOUT = 240.0  # s: a bound so that a hung example fails instead of hanging the suite
FENCE = re.compile(r"^(?P<indent> *)(?P<fence>`{3,}|~{3,})(?P<info>[^`]*)$")
NOTE = re.compile(r"^<!--\s*(?P<note>.*?)\s*-->$")
README_TEST_LINE = 'pip install -e ".[test]" && pytest'


@dataclass(frozen=True)
class Block:
    """One fenced block of a page, with the notes written right above it."""

    page: Path
    line: int  # 1-based line of the opening fence
    lang: str
    text: str
    not_run: str | None = None
    slow: str | None = None
    bad_note: str | None = None

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def parse_blocks(page: Path) -> list[Block]:
    """Every fenced block of a markdown page (indented ones in lists too), in order."""
    lines = page.read_text().splitlines()
    found: list[Block] = []
    i = 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if opening is None:
            i += 1
            continue
        indent, fence = len(opening["indent"]), opening["fence"]
        info = opening["info"].strip()
        notes = []
        j = i - 1
        while j >= 0 and (comment := NOTE.match(lines[j].strip())):
            notes.append(comment["note"])
            j -= 1
        body = []
        k = i + 1
        while k < len(lines) and not (lines[k].strip().startswith(fence) and lines[k].strip().strip(fence[0]) == ""):
            body.append(lines[k][indent:] if lines[k][:indent].strip() == "" else lines[k])
            k += 1
        not_run = slow = bad = None
        for note in notes:
            if note.startswith("not run"):
                reason = note.removeprefix("not run").lstrip(":").strip()
                not_run, bad = (reason, bad) if note.startswith("not run:") and reason else (None, note)
            elif note.startswith("slow"):
                slow = note.removeprefix("slow").lstrip(":").strip() or "slow"
        found.append(Block(page, i + 1, info.split()[0] if info else "", "\n".join(body) + "\n", not_run, slow, bad))
        i = k + 1
    return found


BLOCKS = [block for page in PAGES for block in parse_blocks(page)]
EXAMPLES = [block for block in BLOCKS if block.lang in RUNNABLE]
# The README repeats some blocks of the quick start page word for word: each runs once, under
# the id of its first occurrence.
UNIQUE: list[Block] = []
for _block in EXAMPLES:
    if all((b.lang, b.text, b.not_run) != (_block.lang, _block.text, _block.not_run) for b in UNIQUE):
        UNIQUE.append(_block)


def script_of(block: Block) -> str:
    """What bash runs: the whole block, or for `console` the commands after `$ ` (with their continuations)."""
    if block.lang != "console":
        return block.text
    commands, continued = [], False
    for line in block.text.splitlines():
        if line.startswith("$ ") or continued:
            commands.append(line.removeprefix("$ "))
            continued = line.rstrip().endswith("\\")
    return "\n".join(commands) + "\n"


def run_block(block: Block, where: Path) -> subprocess.CompletedProcess[str]:
    """Run one example in `where` as a reader would; every process it started is ended after."""
    for name in LINKED:
        if not (where / name).exists():
            (where / name).symlink_to(ROOT / name, target_is_directory=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MHRC_", "PYTEST_"))}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["NO_MKDOCS_2_WARNING"] = "1"
    # the docs name Zenoh's usual port; here each example gets a free one, so a world left by
    # anything else on 7447 can never answer in its place
    text = (block.text if block.lang == "python" else script_of(block)).replace("7447", str(free_port()))
    if block.lang == "python":
        is_test = re.search(r"^(async )?def test_", block.text, re.M) is not None
        source = where / ("test_example.py" if is_test else "example.py")
        source.write_text(text)
        cmd = (
            [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "asyncio_mode=auto", source.name]
            if is_test
            else [sys.executable, source.name]
        )
    else:
        (where / "example.sh").write_text(text)
        cmd = ["bash", "-e", "-o", "pipefail", "example.sh"]
    proc = subprocess.Popen(
        cmd,
        cwd=where,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        out, _ = proc.communicate(timeout=EXAMPLE_TIMEOUT)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"{block.id}: still running after {EXAMPLE_TIMEOUT:.0f} s; output:\n{out[-4000:]}")
    finally:
        try:  # what the block left in the background (a world waiting for agents that failed)
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return subprocess.CompletedProcess(cmd, proc.returncode, out, "")


def check_block(block: Block, where: Path) -> None:
    result = run_block(block, where)
    assert result.returncode == 0, (
        f"{block.id} ({block.lang}) exited with {result.returncode}:\n{result.stdout[-4000:]}"
    )


# An example that runs an episode, a world, a benchmark or Python is in the slow tier (it takes
# seconds to minutes); the fast tier keeps those that only ask the CLI (--help, --dry-run, schema).
RUNS_SOMETHING = re.compile(
    r"\bmhrc (up|world|agent|render|show|report|router|bus|doctor)\b|\bmhrc eval\b(?!.*--dry-run)|bench/|pytest|python"
)


def in_slow_tier(block: Block) -> bool:
    return bool(block.slow) or block.lang == "python" or RUNS_SOMETHING.search(block.text) is not None


@pytest.mark.parametrize(
    "block", [pytest.param(b, id=b.id, marks=[pytest.mark.slow] if in_slow_tier(b) else []) for b in UNIQUE]
)
def test_example_runs(block: Block, tmp_path: Path) -> None:
    assert block.bad_note is None, f"{block.id}: `<!-- {block.bad_note} -->` must read `<!-- not run: REASON -->`"
    if block.not_run:
        pytest.skip(f"{block.id}: {block.not_run}")
    check_block(block, tmp_path)


def test_every_fence_names_its_language() -> None:
    unnamed = [b.id for b in BLOCKS if not b.lang]
    assert not unnamed, f"fences without a language (commands: bash or python; listings: text): {unnamed}"
    misplaced = [b.id for b in BLOCKS if (b.not_run or b.bad_note) and b.lang not in RUNNABLE]
    assert not misplaced, f"`not run` notes above blocks that are not examples anyway: {misplaced}"


def test_the_examples_are_collected() -> None:
    """The collection itself: a page full of examples must not silently yield none."""
    by_page = {b.page.name for b in EXAMPLES if not b.not_run}
    assert {"README.md", "quickstart.md", "protocol.md", "testing.md", "security.md"} <= by_page
    block = parse_blocks(ROOT / "docs" / "fidelity.md")
    assert [b.lang for b in block] == ["bash", "text", "bash", "text"]


def test_a_failing_example_fails(tmp_path: Path) -> None:
    """The runner can fail: a command that exits non-zero midway, a background process left over."""
    page = ROOT / "docs" / "index.md"
    with pytest.raises(AssertionError, match="exited with 3"):
        check_block(Block(page, 1, "bash", "true\n(exit 3)\necho never\n"), tmp_path)
    with pytest.raises(AssertionError, match="exited with 1"):
        check_block(Block(page, 1, "python", "import sys\nsys.exit(1)\n"), tmp_path)
    with pytest.raises(AssertionError, match="exited with 1"):
        check_block(Block(page, 1, "python", "def test_no():\n    assert False\n"), tmp_path)
    check_block(
        Block(page, 1, "console", "$ mhrc --help > help.txt\nUsage: mhrc [OPTIONS]\n$ grep -q 'mhrc up' help.txt\n"),
        tmp_path,
    )
    with pytest.raises(AssertionError, match="exited with 2"):
        check_block(Block(page, 1, "bash", "mhrc up --no-such-option\n"), tmp_path)


def test_notes_are_read(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "<!-- not run: needs a docker engine -->\n```bash\ndocker ps\n```\n\n"
        "<!-- slow: a minute -->\n```bash\nmhrc eval\n```\n\n"
        "<!-- not run -->\n```bash\nls\n```\n\n"
        "- in a list:\n\n  ```python\n  print(1)\n  ```\n\n```\nbare\n```\n"
    )
    got = parse_blocks(page)
    assert [(b.lang, b.not_run, b.slow, b.bad_note) for b in got] == [
        ("bash", "needs a docker engine", None, None),
        ("bash", None, "a minute", None),
        ("bash", None, None, "not run"),
        ("python", None, None, None),
        ("", None, None, None),
    ]
    assert got[3].text == "print(1)\n"


def test_readme_is_short_and_keeps_ci_line() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    (block,) = [b for b in parse_blocks(ROOT / "README.md") if README_TEST_LINE in b.text.splitlines()]
    # .ci/run runs the block's lines as written: a fresh venv, then the install and the suite
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    lines = [line for line in block.text.splitlines() if line.strip()]
    assert lines[0].startswith("python3 -m venv ") and all(line in ci for line in lines), (lines, ci)
    assert [ci.index(line) for line in lines] == sorted(ci.index(line) for line in lines)
    linked = re.findall(r"\]\((docs/[^)#]+)", text)
    assert linked and all((ROOT / link).is_file() for link in linked), [
        link for link in linked if not (ROOT / link).is_file()
    ]


def test_readme_install_lists_every_extra_one_line_each() -> None:
    """A newcomer needs the env and rerun extras on day one: the Install block names every extra
    of pyproject.toml, each on its own line."""
    import tomllib

    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    text = (ROOT / "README.md").read_text()
    install = text[text.index("## Install") : text.index("\n## ", text.index("## Install") + 1)]
    (block,) = [b for b in parse_blocks(ROOT / "README.md") if b.text.startswith("pip install -e .  ")]
    assert block.text in install
    lines = block.text.splitlines()
    for extra in extras:
        assert sum(f'pip install -e ".[{extra}]"' in line for line in lines) == 1, extra


# --------------------------------------------------------------------------- the site


def load_hook(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"docs_hook_{name}", ROOT / "docs" / "hooks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bench_placeholders_render_from_the_json(tmp_path: Path) -> None:
    bench = load_hook("bench")
    (tmp_path / "rt.json").write_text(
        json.dumps(
            {
                "open": {"p50": 1.5, "n": 300},
                "tls": {"p50": 1.71234, "n": 300},
                "speedup": 2.5,
                "runs": [{"mode": "a", "t": {"p50": 0.25}}, {"mode": "b", "t": None}],
            }
        )
    )
    assert bench.render("rt:speedup", tmp_path) == "2.5"
    table = bench.render("rt", tmp_path).splitlines()
    assert table[:4] == ["|  | p50 | n |", "| --- | --- | --- |", "| open | 1.5 | 300 |", "| tls | 1.71 | 300 |"]
    assert "bench/results/rt.json" in table[-1]
    assert bench.render("rt:runs | mode | first=t.p50", tmp_path).splitlines()[2:4] == ["| a | 0.25 |", "| b | - |"]
    assert bench.render("rt:open", tmp_path).splitlines()[2] == "| p50 | 1.5 |"
    for bad in ("nothing", "rt:missing", "rt:runs | mode | t.p99", "rt:speedup | x"):
        with pytest.raises(bench.BenchError):
            bench.render(bad, tmp_path)


def test_a_bad_placeholder_is_a_warning(caplog: pytest.LogCaptureFixture) -> None:
    """mkdocs --strict fails on warnings: a placeholder naming no figure must be one."""
    bench = load_hook("bench")
    page = SimpleNamespace(file=SimpleNamespace(src_path="benchmarks.md"))
    with caplog.at_level(logging.WARNING, logger="mkdocs"):
        out = bench.on_page_markdown("a <!-- bench: no_such_results --> b", page)
    assert "benchmark figure missing" in out
    assert any("no_such_results" in r.getMessage() and r.levelno == logging.WARNING for r in caplog.records)


def test_the_benchmarks_page_holds_its_figures_as_the_json_has_them() -> None:
    """docs/benchmarks.md read as it is (on GitHub, nothing built) shows every figure: each
    placeholder is followed by the figure bench/results holds now (`python docs/hooks/bench.py`
    writes them), not left for the site's build to fill in."""
    bench = load_hook("bench")
    page = (ROOT / "docs" / "benchmarks.md").read_text()
    problems: list[str] = []
    assert bench.fill(page, problems=problems) == page, "stale figures: run python docs/hooks/bench.py"
    assert not problems
    placeholders = len(bench.PLACEHOLDER.findall(page))
    assert placeholders > 40 and page.count(bench.END) == placeholders
    p50 = bench.render("bus:cross_process.result_ms_p50")
    assert f"| cross_process | {bench.render('bus:cross_process.ack_ms_p50')} | " in page and p50 in page


def test_writing_the_figures_is_idempotent_and_a_stale_page_fails_the_build(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    bench = load_hook("bench")
    (tmp_path / "rt.json").write_text(json.dumps({"speedup": 2.5, "open": {"p50": 1.5, "n": 300}}))
    page = "Faster by <!-- bench: rt:speedup -->x.\n\n<!-- bench: rt -->\n\nAfter.\n"
    once = bench.fill(page, tmp_path)
    assert "Faster by <!-- bench: rt:speedup -->2.5<!-- /bench -->x." in once
    assert "<!-- bench: rt -->\n\n|  | p50 | n |" in once and once.endswith("<!-- /bench -->\n\nAfter.\n")
    assert bench.fill(once, tmp_path) == once  # a second run changes nothing
    (tmp_path / "rt.json").write_text(json.dumps({"speedup": 3.0, "open": {"p50": 1.5, "n": 300}}))
    again = bench.fill(once, tmp_path)
    assert "-->3<!--" in again and again.count("<!-- bench:") == 2 and again.count(bench.END) == 2
    page_of = SimpleNamespace(file=SimpleNamespace(src_path="benchmarks.md"))
    with caplog.at_level(logging.WARNING, logger="mkdocs"):  # a placeholder with no figure written: the build fails
        bench.on_page_markdown("p50: <!-- bench: bus:cross_process.result_ms_p50 --> ms", page_of)
    assert any("not those of bench/results" in r.getMessage() for r in caplog.records)


def test_the_site_builds_strict(tmp_path: Path) -> None:
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=EXAMPLE_TIMEOUT,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert not [line for line in proc.stderr.splitlines() if line.startswith("WARNING")]
    bench = load_hook("bench")
    benchmarks = (site / "benchmarks" / "index.html").read_text()
    assert "benchmark figure missing" not in benchmarks
    p50 = bench.render("bus:cross_process.result_ms_p50")  # the figure as the JSON has it now
    assert f"<td>{p50}</td>" in benchmarks
    api = {page: (site / "reference" / page / "index.html").read_text() for page in ("protocol", "policy", "testing")}
    assert 'id="mhrc.core.protocol.ActionRequest"' in api["protocol"]
    assert 'id="mhrc.agents.policy.Policy"' in api["policy"]
    assert 'id="mhrc.testing.ScriptedModelServer"' in api["testing"]
