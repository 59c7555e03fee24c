"""A shared or tampered evaluation directory is validated, never trusted (issue 42): each tampered
file is one line naming it, exit 2, no traceback, and nothing is written, by `mhrc eval --resume`
and by `mhrc report` alike; no file of the directory is followed through a symlink; a link of
the summary page is only ever a relative path to an episode's report."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from mhrc.cli import main
from mhrc.eval.html import html_summary
from mhrc.eval.records import EvalManifest, read_rows, upgrade_row
from mhrc.eval.spec import EvalSpec
from mhrc.eval.summary import Summary

SPEC = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3, 4), horizon=12)  # a 2-episode grid
KEYS = ("pack_objects/kitchen/3/0", "pack_objects/kitchen/4/0")


def _row(key: str, **extra: Any) -> dict[str, Any]:
    """A finished heuristic row of SPEC's grid, as episodes.jsonl holds it."""
    task, scene, n, seed = key.split("/")
    robots = ["alice", "bob", "david"]
    return _full(
        {
            "key": key,
            "method": "heuristic",
            "ablation": "none",
            "task": task,
            "scene": scene,
            "seed": int(seed),
            "n_objects": int(n),
            "robots": robots,
            "reason": "success",
            "success": True,
            "placed": int(n),
            "total": int(n),
            "partial_success": 1.0,
            "temporal_steps": 10,
            "action_steps": 20,
            "action_steps_per_robot": {"alice": 8, "bob": 6, "david": 6},
            "fidelity": "paper",
            "horizon": 12,
            "schedule": "sequential",
            "trace": f"traces/{key.replace('/', '_')}.jsonl",
            **extra,
        }
    )


def _full(row: dict[str, Any]) -> dict[str, Any]:
    """A row as episodes.jsonl holds it, with every field's old meaning filled in."""
    return dict(upgrade_row(row).flat())


def _evaluation(d: Path, rows: list[dict[str, Any]] | None = None) -> Path:
    """An evaluation directory of SPEC: its manifest, its rows (default: both episodes, solved)."""
    (d / "traces").mkdir(parents=True)
    (d / "eval.json").write_text(EvalManifest(identity=SPEC.identity(), spec=SPEC).text())
    rows = [_row(k) for k in KEYS] if rows is None else rows
    (d / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return d


def _snapshot(*roots: Path) -> dict[str, Any]:
    """Every entry under `roots` as it is on disk: a file's bytes, a link's target (never followed)."""
    out: dict[str, Any] = {}
    for root in roots:
        for here, dirs, files in os.walk(root):
            for name in dirs + files:
                p = Path(here) / name
                out[str(p)] = os.readlink(p) if p.is_symlink() else (p.read_bytes() if p.is_file() else "dir")
    return out


def _refused(args: list[str], fragment: str, *watched: Path) -> None:
    """The command exits 2 with one line naming the cause (`fragment`), no traceback, and nothing
    under `watched` changes."""
    before = _snapshot(*watched)
    result = CliRunner().invoke(main, args)
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error")]
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    assert len(errors) == 1 and fragment in errors[0], result.stderr
    assert "Traceback" not in result.output and isinstance(result.exception, SystemExit), result.output
    assert _snapshot(*watched) == before, "a refused command wrote something"


def _rows_with(change: Callable[[dict[str, Any]], None]) -> list[dict[str, Any]]:
    rows = [_row(k) for k in KEYS]
    change(rows[0])
    return rows


def _line(rows: list[dict[str, Any]]) -> bytes:
    return "".join(json.dumps(r) + "\n" for r in rows).encode()


NESTED = b"[" * 100_000 + b"]" * 100_000  # json.loads: RecursionError


# (name, the episodes.jsonl bytes, what the one line says)
BAD_ROWS = [
    ("PS 7.5", _line(_rows_with(lambda r: r.update(partial_success=7.5))), "partial_success"),
    ("TS -3", _line(_rows_with(lambda r: r.update(temporal_steps=-3))), "temporal_steps"),
    ("forged success", _line(_rows_with(lambda r: r.update(success="true"))), "success"),
    ("success 1", _line(_rows_with(lambda r: r.update(success=1))), "success"),
    ("10^30", _line(_rows_with(lambda r: r.update(temporal_steps=10**30))), "temporal_steps"),
    ("NaN wall time", _line(_rows_with(lambda r: r.update(wall_time=float("nan")))), "wall_time"),
    ("steps as a string", _line(_rows_with(lambda r: r.update(action_steps="20"))), "action_steps"),
    (
        "3 episodes in a 2-episode grid",
        _line([_row(k) for k in KEYS] + [_row("pack_objects/kitchen/5/0")]),
        "line 3: episode pack_objects/kitchen/5/0 is not in this evaluation's grid",
    ),
    ("a key twice", _line([_row(KEYS[0]), _row(KEYS[1]), _row(KEYS[0])]), "line 3: episode"),
    (
        "a key that is not its episode's",
        _line(_rows_with(lambda r: r.update(key=KEYS[1]))),
        "is not its episode's",
    ),
    (
        "unknown protocol",
        _line(_rows_with(lambda r: r.update(protocol="nope"))),
        "protocol: Value error, unknown protocol 'nope'",
    ),
    (
        "a protocol its key does not say",
        _line(_rows_with(lambda r: r.update(protocol="centralized"))),
        "is not its episode's ('@centralized/",
    ),
    ("javascript: trace", _line(_rows_with(lambda r: r.update(trace="javascript:alert(1)"))), "trace"),
    ("../ trace", _line(_rows_with(lambda r: r.update(trace="traces/../../evil.jsonl"))), "trace"),
    ("absolute trace", _line(_rows_with(lambda r: r.update(trace="/etc/passwd"))), "trace"),
    ("nested JSON", _line([_row(KEYS[0])]) + NESTED + b"\n", "line 2: nested too deeply"),
    ("non-UTF-8", _line([_row(KEYS[0])]) + b'{"key": "\xff\xfe"}\n', "line 2: not UTF-8"),
    ("not JSON mid-file", b"{torn\n" + _line([_row(KEYS[0])]), "line 1: not JSON"),
    ("a list", _line([_row(KEYS[0])]) + b"[1, 2]\n", "line 2: not an episode row"),
]


@pytest.mark.parametrize(("name", "data", "fragment"), BAD_ROWS, ids=[b[0] for b in BAD_ROWS])
def test_a_tampered_row_is_one_line_and_nothing_is_written(
    tmp_path: Path, name: str, data: bytes, fragment: str
) -> None:
    d = _evaluation(tmp_path / "ev")
    (d / "episodes.jsonl").write_bytes(data)
    rows = str(d / "episodes.jsonl")
    _refused(["eval", "--resume", "--out", str(d)], fragment, tmp_path)
    _refused(["eval", "--resume", "--out", str(d), "--rerun", str(tmp_path / "rrd")], fragment, tmp_path)
    _refused(["report", str(d)], fragment, tmp_path)
    _refused(["report", str(d), "--out", str(tmp_path / "r.md")], fragment, tmp_path)
    result = CliRunner().invoke(main, ["report", str(d)])
    assert rows in result.stderr, result.stderr  # the file is named


def _manifest(change: Callable[[dict[str, Any]], None]) -> bytes:
    raw = json.loads(EvalManifest(identity=SPEC.identity(), spec=SPEC).text())
    change(raw)
    return json.dumps(raw).encode()


BAD_MANIFESTS = [
    ("unknown identity field", _manifest(lambda m: m["identity"].update(colour="blue")), "identity.colour"),
    ("string horizon", _manifest(lambda m: m["identity"].update(horizon="12")), "identity.horizon"),
    ("horizon 10^30", _manifest(lambda m: m["identity"].update(horizon=10**30)), "identity.horizon"),
    ("unknown top field", _manifest(lambda m: m.update(extra=1)), "extra"),
    ("unknown spec field", _manifest(lambda m: m["spec"].update(colour="blue")), "spec.colour"),
    ("spec and identity apart", _manifest(lambda m: m["spec"].update(horizon=30)), "does not make its identity"),
    ("a grid of 10^30 repeats", _manifest(lambda m: m["spec"].update(repeats=10**30)), "spec.repeats"),
    (
        "unknown protocol",
        _manifest(lambda m: (m["identity"].update(protocols=["nope"]), m["spec"].update(protocols=["nope"]))),
        "identity.protocols: Value error, unknown protocol 'nope'",
    ),
    (
        "a protocol the grid did not run",
        _manifest(lambda m: m["spec"].update(protocols=["centralized", "mhrc"])),
        "does not make its identity: protocols",
    ),
    ("nested", b'{"identity": ' + NESTED + b"}", "nested too deeply"),
    ("non-UTF-8", b'{"identity": "\xff"}', "not UTF-8"),
]


@pytest.mark.parametrize(("name", "data", "fragment"), BAD_MANIFESTS, ids=[b[0] for b in BAD_MANIFESTS])
def test_a_tampered_manifest_is_one_line_and_nothing_is_written(
    tmp_path: Path, name: str, data: bytes, fragment: str
) -> None:
    d = _evaluation(tmp_path / "ev")
    (d / "eval.json").write_bytes(data)
    _refused(["eval", "--resume", "--out", str(d)], fragment, tmp_path)
    _refused(["report", str(d), "--out", str(tmp_path / "r.md")], fragment, tmp_path)


@pytest.mark.parametrize("name", ["episodes.jsonl", "eval.json", "summary.html", "traces", "traces/x.html"])
def test_no_file_of_the_directory_is_followed_through_a_symlink(tmp_path: Path, name: str) -> None:
    """The link's target is another file of the user's: it is never read as the evaluation's, nor rewritten."""
    d = _evaluation(tmp_path / "ev")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    target = elsewhere / Path(name).name
    link = d / name
    if name == "traces":
        target.mkdir()
        (link).rmdir()
    elif link.exists():
        target.write_bytes(link.read_bytes())
        link.unlink()
    else:
        target.write_text("<p>someone's page</p>")
    link.symlink_to(target)
    _refused(["eval", "--resume", "--out", str(d)], "symlink", tmp_path)
    if name in ("episodes.jsonl", "eval.json"):
        _refused(["report", str(d)], "symlink", tmp_path)


def test_a_sound_directory_is_read_and_reported(tmp_path: Path) -> None:
    """The fixture itself passes: what the tests above refuse is the tampering, not the directory."""
    d = _evaluation(tmp_path / "ev")
    assert [r.key for r in read_rows(d / "episodes.jsonl", set(KEYS))] == list(KEYS)
    result = CliRunner().invoke(main, ["report", str(d), "--out", str(tmp_path / "r.md")])
    assert result.exit_code == 0, result.output
    assert 'href="ev/traces/pack_objects_kitchen_3_0.html"' in (tmp_path / "r.html").read_text()


@pytest.mark.parametrize(
    "trace",
    [
        "javascript:alert(1)",
        "javascript:alert(1).jsonl",
        "/etc/passwd",
        "../x.jsonl",
        "traces/../../x.jsonl",
        "https://e.x/a.jsonl",
    ],
)
def test_a_row_in_memory_whose_trace_is_no_file_of_traces_gets_no_link(trace: str) -> None:
    """The page is drawn from rows a caller may hand over unchecked: still, no such trace becomes an href."""
    row = upgrade_row(_row(KEYS[0]))
    unchecked = row.model_copy(update={"trace": trace})  # never validated
    page = html_summary([unchecked], [None], resamples=20)
    assert page.count("<a href=") == 0 and "javascript:" not in page.split("<h2>Episodes</h2>")[1]
    from mhrc.eval.html import links_of

    (link,) = links_of([unchecked], Path("ev"), Path("."))
    assert link is None
    page = html_summary([row], links_of([row], Path("ev"), Path(".")), resamples=20)
    assert '<a href="ev/traces/pack_objects_kitchen_3_0.html">' in page


def test_links_stay_with_their_rows_when_the_summary_sorts_them() -> None:
    """Rows in the order episodes finished (kitchen, then bedroom); the page lists them by key, each with its own link."""
    rows = [upgrade_row(_row("pack_objects/kitchen/3/0")), upgrade_row(_row("pack_objects/bedroom/3/0"))]
    links = [f"traces/{r.key.replace('/', '_')}.html" for r in rows]
    summary = Summary.of(rows, resamples=20, links=links)
    assert [(r.key, link) for r, link in zip(summary.rows, summary.links)] == [
        ("pack_objects/bedroom/3/0", "traces/pack_objects_bedroom_3_0.html"),
        ("pack_objects/kitchen/3/0", "traces/pack_objects_kitchen_3_0.html"),
    ]
    page = html_summary(rows, links, resamples=20)
    for r, link in zip(rows, links):
        assert f"<td>{r.key}</td>" in page
        row_html = page.split(f"<td>{r.key}</td>", 1)[1].split("</tr>", 1)[0]
        assert f'href="{link}"' in row_html, row_html
