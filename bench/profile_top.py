"""The top frames of a py-spy speedscope profile: each function's share of the samples (inclusive),
over the whole profile or under one frame (e.g. Sim.execute: the simulator's skills).

    py-spy record --subprocesses -f speedscope -o X.speedscope.json -- mhrc eval --workers 1 ...
    python bench/profile_top.py X.speedscope.json[.gz] [--under Sim.execute] [--top 40] [--out X.top.json]
"""

from __future__ import annotations

import argparse
import gzip
import json
from collections import Counter
from pathlib import Path
from typing import Any

from report import emit


def load(path: Path) -> dict[str, Any]:
    raw = path.read_bytes()
    return dict(json.loads(gzip.decompress(raw) if path.suffix == ".gz" else raw))


def top(profile: dict[str, Any], under: str | None, n: int) -> dict[str, Any]:
    frames = profile["shared"]["frames"]
    names = [f"{f['name']} ({Path(f.get('file') or '?').name})" for f in frames]
    inclusive: Counter[str] = Counter()
    own: Counter[str] = Counter()
    total = 0.0
    for prof in profile["profiles"]:
        for stack, weight in zip(prof["samples"], prof["weights"]):
            chain = [names[i] for i in stack]
            if under is not None:
                at = next((k for k, name in enumerate(chain) if name.startswith(under + " ")), None)
                if at is None:
                    continue
                chain = chain[at:]
            total += weight
            for name in set(chain):
                inclusive[name] += weight
            if chain:
                own[chain[-1]] += weight
    share = lambda c: {k: round(v / total, 4) for k, v in c.most_common(n)}  # noqa: E731
    return {"under": under, "samples_s": round(total, 2), "inclusive": share(inclusive), "self": share(own)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("profile", type=Path)
    ap.add_argument("--under", default=None, help="only samples under this function (its name as py-spy gives it)")
    ap.add_argument("--top", type=int, default=40)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    emit(top(load(args.profile), args.under, args.top), args.out)


if __name__ == "__main__":
    main()
