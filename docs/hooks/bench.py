"""Benchmark figures on the docs pages, written into the pages from `bench/results/*.json`.

A page holds a placeholder where a figure or a table belongs, and after it the figure as the
last benchmark run wrote it, up to `<!-- /bench -->`: the page reads as it is, on GitHub too.
`python docs/hooks/bench.py` rewrites those figures from the JSON (bench/run_all.sh runs it after
the benchmarks); as a MkDocs hook it checks them, and a page whose figures are not the JSON's is
a warning, which fails `mkdocs build --strict`:

    <!-- bench: bus:in_process.result_ms_p50 -->           one value, inline
    <!-- bench: bus -->                                      a table of the file's dict rows
    <!-- bench: eval_grid:runs | fidelity | Succ=all.succ | TS=all.ts -->   chosen columns

`NAME` is a file of `bench/results/` without `.json`; the optional `:PATH` is a dotted path into
it (list items by index: `models.0.runs`). A value renders inline. A dict or list renders as
a table, one row per member that is a dict; without columns, every scalar field of the rows
is a column; with columns (`| FIELD` or `| HEADER=FIELD`, dotted paths inside a row), those.
A key becomes a header people read (`heading`: `result_ms_p50` is "result p50 (ms)"); a HEADER
given in the placeholder is kept as written.
A dict with no dict member is one record: one row of the columns, or without them a table of
field and value.
Each table says which file it came from. A placeholder that names a missing file, path or
field is a warning too. (`bench/report.py` only writes the JSON; the tables are made here.)

Filled, a value sits inline (`<!-- bench: X -->2.5<!-- /bench -->`), a table between blank lines.
"""

from __future__ import annotations

import json
import logging
import re
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "bench" / "results"
PLACEHOLDER = re.compile(r"<!--\s*bench:\s*(?P<spec>.*?)\s*-->")
END = "<!-- /bench -->"
# a placeholder and, when filled, its figure up to END (never across another placeholder)
FIGURE = re.compile(
    r"<!--\s*bench:\s*(?P<spec>.*?)\s*-->(?:(?P<body>(?:(?!<!--\s*bench:).)*?)<!--\s*/bench\s*-->)?", re.S
)
log = logging.getLogger("mkdocs.hooks.bench")


class BenchError(ValueError):
    """A placeholder that does not name a figure of the results."""


def fmt(value: Any) -> str:
    """One cell: floats rounded for reading (the JSON keeps every digit), lists joined."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if value is None:
        return "-"
    if isinstance(value, float):
        if abs(value) >= 100:
            return f"{value:.1f}"
        if abs(value) >= 1:
            return f"{value:.2f}".rstrip("0").rstrip(".")
        return f"{value:.3g}"
    if isinstance(value, list):
        return ", ".join(fmt(v) for v in value) if value else "-"
    return str(value).replace("|", "\\|").replace("\n", " ")


WORDS = {"succ": "Succ", "ps": "PS", "ts": "TS", "as": "AS", "llm": "LLM"}  # the metrics as the pages write them
UNITS = {"ms": "ms", "s": "s"}
STATS = ("p50", "p99", "mean", "min", "max")


def heading(name: str) -> str:
    """A column header for a JSON key, as people read it: `result_ms_p50` -> `result p50 (ms)`,
    `llm_calls` -> `LLM calls`, `succ` -> `Succ` (headers a placeholder names itself are kept)."""
    parts = name.split("_")
    units = [p for p in parts if p in UNITS]
    words = [WORDS.get(p, p) for p in parts if p not in UNITS and p not in STATS]
    words += [p for p in parts if p in STATS]
    return " ".join(words) + (f" ({UNITS[units[0]]})" if units else "")


def lookup(data: Any, path: str, where: str) -> Any:
    """The member at a dotted path (list items by index); None where the path passes a null."""
    node = data
    for part in [p for p in path.split(".") if p]:
        if node is None:  # a record without this measure (e.g. no first token when not streamed)
            return None
        if isinstance(node, dict) and part in node:
            node = node[part]
        elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        else:
            raise BenchError(f"{where}: no {part!r} in {path!r}")
    return node


def table(node: Any, columns: list[tuple[str, str]], label: str, where: str) -> str:
    """A markdown table of the dict members of `node`, one row each."""
    items = list(node.items()) if isinstance(node, dict) else [(None, v) for v in node]
    rows = [(key, row) for key, row in items if isinstance(row, dict)]
    if not rows and isinstance(node, dict):  # one record: a row of the chosen fields, or field | value
        if columns:
            return table([node], columns, label, where)
        return "\n".join(["| field | value |", "| --- | --- |", *(f"| {heading(k)} | {fmt(v)} |" for k, v in items)])
    if not rows:
        raise BenchError(f"{where}: nothing to tabulate (no member is an object)")
    if not columns:
        names: dict[str, None] = {}
        for _, row in rows:
            names.update({k: None for k, v in row.items() if not isinstance(v, dict)})
        columns = [(heading(name), name) for name in names]
    keyed = isinstance(node, dict)
    header = ([heading(label)] if keyed else []) + [h for h, _ in columns]
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for key, row in rows:
        cells = [fmt(lookup(row, field, f"{where} row {key!r}")) for _, field in columns]
        lines.append("| " + " | ".join(([str(key)] if keyed else []) + cells) + " |")
    return "\n".join(lines)


def render(spec: str, results: Path = RESULTS) -> str:
    """The markdown for one placeholder's `spec` (what follows `bench:`)."""
    head, *cols = [part.strip() for part in spec.split("|")]
    name, _, path = head.partition(":")
    name = name.strip()
    source = results / f"{name}.json"
    where = f"bench/results/{name}.json"
    if not name or not source.is_file():
        raise BenchError(f"no benchmark results {where} (placeholder {spec!r})")
    node = lookup(json.loads(source.read_text()), path.strip(), where)
    if not isinstance(node, (dict, list)) or (isinstance(node, list) and not any(isinstance(v, dict) for v in node)):
        if cols:
            raise BenchError(f"{where}: {path!r} is a value, not a table; drop the columns")
        return fmt(node)
    columns = [(h.strip(), f.strip()) if sep else (heading(c), c) for c in cols for h, sep, f in [c.partition("=")]]
    label = path.strip().split(".")[-1] if path.strip() else ""
    return f"{table(node, columns, label, where)}\n\n*From `{where}`{f' (`{path.strip()}`)' if path.strip() else ''}.*"


def fill(markdown: str, results: Path = RESULTS, problems: list[str] | None = None) -> str:
    """`markdown` with every placeholder followed by its figure as `results` has it now (a figure
    already there is replaced); a placeholder naming no figure gets a bold note, and `problems` its reason."""

    def replace(match: re.Match[str]) -> str:
        spec = match.group("spec")
        try:
            figure = render(spec, results)
        except (BenchError, ValueError) as exc:
            if problems is not None:
                problems.append(str(exc))
            figure = f"**(benchmark figure missing: {exc})**"
        body = f"\n\n{figure}\n\n" if "\n" in figure else figure
        return f"<!-- bench: {spec} -->{body}{END}"

    return FIGURE.sub(replace, markdown)


def on_page_markdown(markdown: str, page: Any, **kwargs: Any) -> str:
    """MkDocs' hook: a placeholder naming no figure, or a page whose figures are not those of
    bench/results (run `python docs/hooks/bench.py`), is a warning (strict fails)."""
    problems: list[str] = []
    filled = fill(markdown, problems=problems)
    for problem in problems:
        log.warning("%s: %s", page.file.src_path, problem)
    if not problems and filled != markdown:
        log.warning(
            "%s: its benchmark figures are not those of bench/results; write them with `python docs/hooks/bench.py`",
            page.file.src_path,
        )
    return filled


def main(pages: list[str]) -> int:
    """Write the figures into `pages` (default: every docs page with a placeholder); 1 if one names no figure."""
    paths = [Path(p) for p in pages] or sorted(
        p for p in (ROOT / "docs").glob("*.md") if PLACEHOLDER.search(p.read_text())
    )
    failed = 0
    for path in paths:
        problems: list[str] = []
        text = path.read_text()
        filled = fill(text, problems=problems)
        for problem in problems:
            print(f"{path}: {problem}", file=sys.stderr)
        failed += bool(problems)
        if filled != text:
            path.write_text(filled)
            print(f"{path}: figures written from bench/results", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
