"""The suite's `--dist loadgroup` (pyproject's addopts) really groups: the tests of one
`xdist_group` run on one worker. pytest 9.2 changed how a test's id is stored, and
pytest-xdist 3.8's loadgroup, which marks a grouped test by appending `@GROUP` to that id, lost
its groups without a word (pytest-xdist#1386): `test_play_browser`'s module fixture, a 40 s
episode in a browser, was then built on both workers, and the whole-machine tests were spread
over both. This runs pytest with the suite's distribution, on two workers, over a module of its own."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # it starts two xdist workers: seconds, for a guard of the slow tier

MODULE = """
import os
import pytest

pytestmark = pytest.mark.xdist_group("together")

@pytest.mark.parametrize("i", range(8))
def test_grouped(i):
    with open(os.environ["WHERE"], "a") as out:
        out.write(os.environ["PYTEST_XDIST_WORKER"] + "\\n")
"""


def test_an_xdist_group_runs_on_one_worker(tmp_path: Path) -> None:
    (tmp_path / "test_grouped.py").write_text(MODULE)
    where = tmp_path / "workers.txt"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-p",
            "no:cacheprovider",
            "-n",
            "2",
            "--dist",
            "loadgroup",
            "-q",
            "-c",
            "/dev/null",
            "--rootdir",
            str(tmp_path),
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "WHERE": str(where)},
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    workers = where.read_text().split()
    assert len(workers) == 8 and len(set(workers)) == 1, workers
