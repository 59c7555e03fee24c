"""`mhrc eval --ray ADDRESS` on a real local Ray cluster that this module starts (`ray start
--head` on 127.0.0.1, two CPUs, token authentication on) and stops (`ray stop --force`); the
drivers are real `mhrc eval` processes, the episodes real (heuristic team, PyBullet, Zenoh on
loopback inside each Ray worker). Bad input (no Ray, an old Ray, an address nothing listens
at) needs no cluster."""

from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from waits import interrupt_after_first_row, until_sync

from mhrc.core.endpoints import free_port

MHRC = [sys.executable, "-m", "mhrc"]
SMALL = ["--tasks", "pack_objects", "--scenes", "kitchen"]


@dataclass
class Cluster:
    address: str
    client: str  # ray://127.0.0.1:PORT, the head's Ray Client server
    env: dict[str, str]  # what a driver needs to join it (the token)
    tmp: Path  # the TMPDIR of its workers: an episode's trace lives under it while it runs


@pytest.fixture(scope="module")
def ray_cluster() -> Iterator[Cluster]:
    pytest.importorskip("ray")
    port, client = free_port("127.0.0.1"), free_port("127.0.0.1")
    root = Path(tempfile.mkdtemp(prefix="mhrc-ray-", dir="/tmp"))  # short: Ray's socket paths must fit 107 bytes
    (root / "work").mkdir()
    env = dict(
        os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(16)
    )  # Ray's token authentication, on
    # TMPDIR: where its workers' episodes keep their traces
    cluster_env = dict(env, TMPDIR=str(root / "work"))
    start = [
        sys.executable,
        "-m",
        "ray.scripts.scripts",
        "start",
        "--head",
        "--node-ip-address=127.0.0.1",
        f"--port={port}",
        "--num-cpus=2",
        "--include-dashboard=false",
        "--disable-usage-stats",
        f"--temp-dir={root / 'ray'}",
        f"--ray-client-server-port={client}",
    ]
    try:
        started = subprocess.run(start, env=cluster_env, capture_output=True, text=True, timeout=180)
        assert started.returncode == 0, started.stdout[-2000:] + started.stderr[-2000:]
        yield Cluster(address=f"127.0.0.1:{port}", client=f"ray://127.0.0.1:{client}", env=env, tmp=root / "work")
    finally:
        subprocess.run(
            [sys.executable, "-m", "ray.scripts.scripts", "stop", "--force"], env=env, capture_output=True, timeout=120
        )
        shutil.rmtree(root, ignore_errors=True)


def _client_server_logs(cluster: Cluster) -> str:
    """The ends of the head's Ray Client server logs (the proxy's and each driver session's)."""
    logs = sorted((cluster.tmp.parent / "ray").glob("session_latest/logs/ray_client_server*.err"))
    return "".join(f"\n== {p.name}\n" + "\n".join(p.read_text(errors="replace").splitlines()[-15:]) for p in logs)


def _rows(out: Path) -> list[dict[str, Any]]:
    path = out / "episodes.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def _scores(rows: list[dict[str, Any]]) -> dict[str, tuple[Any, ...]]:
    return {
        r["key"]: (r["success"], r["partial_success"], r["temporal_steps"], r["action_steps"], r["valid"]) for r in rows
    }


# --------------------------------------------------------------------------- on a cluster


# one task in every scene at every size: 12 of the default grid's 36 episodes (tests/test_eval.py
# checks the default grid itself with --dry-run)
GRID = ["--tasks", "pack_objects", "--scenes", "kitchen,bedroom,bathroom"]


@pytest.mark.slow
def test_a_grid_on_ray_gives_the_rows_of_a_local_run(ray_cluster: Cluster, tmp_path: Path) -> None:
    on_ray = subprocess.run(
        [*MHRC, "eval", "--ray", ray_cluster.address, *GRID, "--out", "ray"],
        cwd=tmp_path,
        env=ray_cluster.env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert on_ray.returncode == 0, on_ray.stderr[-3000:]
    assert f"on the Ray cluster at {ray_cluster.address}" in on_ray.stderr
    local = subprocess.run(
        [*MHRC, "eval", "--workers", "2", *GRID, "--out", "local"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert local.returncode == 0, local.stderr[-3000:]
    ray_rows, local_rows = _rows(tmp_path / "ray"), _rows(tmp_path / "local")
    assert len(ray_rows) == 12 and len({r["key"] for r in ray_rows}) == 12
    assert _scores(ray_rows) == _scores(local_rows)
    for r in ray_rows:  # the traces came back through the object store and were written by the driver
        assert (tmp_path / "ray" / r["trace"]).stat().st_size > 0
    assert not (tmp_path / "ray" / "errors.jsonl").exists()
    assert "Table I" in (tmp_path / "ray" / "summary.md").read_text()


def _holder_of(trace_dir: Path) -> tuple[int, Path] | None:
    """(pid, trace) of a process with a running episode's trace open under `trace_dir`."""
    for trace in trace_dir.glob("mhrc-eval-*/trace.jsonl"):
        for fd in Path("/proc").glob("[0-9]*/fd/*"):
            try:
                if os.readlink(fd) == str(trace):
                    return int(fd.parent.parent.name), trace
            except OSError:
                continue
    return None


@pytest.mark.slow
def test_a_ray_worker_killed_mid_episode_costs_no_row(ray_cluster: Cluster, tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [*MHRC, "eval", "--ray", ray_cluster.address, *SMALL, "--objects", "6", "--out", "ev"],
        cwd=tmp_path,
        env=ray_cluster.env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        seen: list[tuple[int, Path]] = []  # the last holder seen

        def under_way() -> bool:  # an episode under way on a Ray worker
            held = _holder_of(ray_cluster.tmp)
            seen[:] = [] if held is None else [held]
            return held is not None and held[1].stat().st_size > 0

        until_sync(
            under_way, "an episode under way", 300, every=0.05, running=proc, said=lambda: proc.communicate()[1][-3000:]
        )
        ((pid, _trace),) = seen
        os.kill(pid, signal.SIGKILL)
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err[-3000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    rows = _rows(tmp_path / "ev")
    assert [r["key"] for r in rows] == ["pack_objects/kitchen/6/0"] and rows[0]["success"], rows
    assert not rows[0]["worker"].endswith(f":{pid}")  # Ray ran it again, in another worker process
    assert not (tmp_path / "ev" / "errors.jsonl").exists()


@pytest.mark.slow
def test_ctrl_c_keeps_the_finished_rows_and_resume_completes_on_ray(ray_cluster: Cluster, tmp_path: Path) -> None:
    args = [
        *MHRC,
        "eval",
        "--ray",
        ray_cluster.address,
        *SMALL,
        "--objects",
        "3,4,5,6",
        "--repeats",
        "2",
        "--out",
        "ev",
    ]
    rows_path = tmp_path / "ev" / "episodes.jsonl"
    # a terminal's Ctrl-C goes to the driver's group (the cluster is not in it)
    returncode, before, text = interrupt_after_first_row(args, tmp_path, rows_path, 300, env=ray_cluster.env)
    assert returncode == 130 and "interrupted: stopping the workers" in text, text[-3000:]
    assert "every finished episode is kept in" in text and "--resume --out ev --ray" in text, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    kept = rows_path.read_text()
    assert kept.startswith(before) and kept.endswith("\n")  # nothing lost or cut
    n_kept = len(kept.splitlines())
    assert 1 <= n_kept < 8
    resumed = subprocess.run(
        [*args, "--resume"], cwd=tmp_path, env=ray_cluster.env, capture_output=True, text=True, timeout=900
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"({n_kept} from before)" in resumed.stderr, resumed.stderr[-3000:]
    rows = _rows(tmp_path / "ev")
    keys = [r["key"] for r in rows]
    assert len(keys) == 8 and len(set(keys)) == 8 and all(r["success"] for r in rows)


@pytest.mark.slow
def test_with_a_shared_out_the_ray_task_writes_the_trace_itself(ray_cluster: Cluster, tmp_path: Path) -> None:
    """One machine: --out is trivially shared. The trace is where the row says, written whole."""
    out = subprocess.run(
        [*MHRC, "eval", "--ray", ray_cluster.address, "--shared-out", *SMALL, "--objects", "3", "--out", "ev"],
        cwd=tmp_path,
        env=ray_cluster.env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    (row,) = _rows(tmp_path / "ev")
    trace = tmp_path / "ev" / row["trace"]
    assert row["success"] and trace.read_text().endswith("\n") and '"episode_done"' in trace.read_text()
    assert sorted(p.name for p in trace.parent.iterdir()) == [
        "pack_objects_kitchen_3_0.html",
        "pack_objects_kitchen_3_0.jsonl",
    ]  # no partial file left


@pytest.mark.slow
def test_a_driver_outside_the_cluster_runs_episodes_through_ray_client(ray_cluster: Cluster, tmp_path: Path) -> None:
    out = subprocess.run(
        [*MHRC, "eval", "--ray", ray_cluster.client, *SMALL, "--objects", "4", "--out", "ev"],
        cwd=tmp_path,
        env=ray_cluster.env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:] + _client_server_logs(ray_cluster)
    (row,) = _rows(tmp_path / "ev")
    assert (
        row["key"] == "pack_objects/kitchen/4/0"
        and row["success"]
        and (tmp_path / "ev" / row["trace"]).stat().st_size > 0
    )


@pytest.mark.slow
def test_a_driver_without_the_clusters_token_is_refused_before_any_episode(
    ray_cluster: Cluster, tmp_path: Path
) -> None:
    env = {k: v for k, v in ray_cluster.env.items() if not k.startswith("RAY_AUTH")} | {
        "HOME": str(tmp_path)
    }  # no ~/.ray/auth_token either
    out = subprocess.run(
        [*MHRC, "eval", "--ray", ray_cluster.address, *SMALL, "--objects", "3", "--out", "ev"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 2, out.stderr[-3000:]
    (line,) = [x for x in out.stderr.splitlines() if x.startswith("Error:")]
    assert line.startswith(f"Error: --ray: could not join the Ray cluster at {ray_cluster.address}: "), out.stderr[
        -3000:
    ]
    assert line.endswith(
        "this driver has no Ray token: set RAY_AUTH_MODE=token and RAY_AUTH_TOKEN (or copy the head's ~/.ray/auth_token)"
    )
    assert "Traceback" not in out.stderr and not (tmp_path / "ev").exists()


def test_llm_episodes_take_a_fraction_of_a_cpu_and_heuristic_ones_a_whole_cpu() -> None:
    from mhrc.eval.cluster import RayExecutor

    assert RayExecutor("auto", concurrency=4, llm=True).num_cpus == 0.25
    assert RayExecutor("auto", concurrency=4, llm=False).num_cpus == 1.0


# --------------------------------------------------------------------------- bad input, no cluster


def _eval_without(fake_ray: str, tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """`mhrc eval` in a process where `import ray` gives `fake_ray` (None: not installed)."""
    code = f"import sys, types\nsys.modules['ray'] = {fake_ray}\nfrom mhrc.cli import main\nmain(sys.argv[1:], prog_name='mhrc')"
    return subprocess.run(
        [sys.executable, "-c", code, "eval", *SMALL, "--out", str(tmp_path / "x"), *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_without_the_ray_extra_eval_says_how_to_install_it(tmp_path: Path) -> None:
    out = _eval_without("None", tmp_path, "--ray", "auto")
    assert out.returncode == 2, out.stderr
    assert (
        out.stderr.strip().splitlines()[-1]
        == 'Error: --ray: Ray is not installed; install the extra: pip install -e ".[ray]"'
    )
    assert "Traceback" not in out.stderr and not (tmp_path / "x").exists()
    local = _eval_without("None", tmp_path, "--dry-run")  # without --ray nothing needs Ray
    assert local.returncode == 0 and "4 episodes" in local.stdout, local.stderr


def test_an_unsupported_ray_version_is_refused(tmp_path: Path) -> None:
    out = _eval_without("types.SimpleNamespace(__version__='2.9.3')", tmp_path, "--ray", "auto")
    assert out.returncode == 2 and "--ray: Ray 2.9.3 is not supported; mhrc needs ray>=2.40" in out.stderr, out.stderr
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("scheme", ["", "ray://"])
def test_an_address_nothing_listens_at_is_one_line(scheme: str, tmp_path: Path) -> None:
    """Returns (no wall-clock assertion: ray.init alone would retry for a minute) with one line."""
    pytest.importorskip("ray")
    address = f"{scheme}127.0.0.1:{free_port('127.0.0.1')}"
    out = subprocess.run(
        [*MHRC, "eval", *SMALL, "--ray", address, "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2, out.stderr
    error = [line for line in out.stderr.splitlines() if line.startswith("Error:")]
    assert error == [
        f"Error: --ray: nothing answers at {address} (Connection refused); start the head with `ray start --head` "
        "(it prints the address), or pass --ray auto on a node of the cluster"
    ], out.stderr
    assert "Traceback" not in out.stderr and not (tmp_path / "x").exists()


class _FlakyRayClient:
    """Stands in for `ray` where a real cluster cannot be made to fail on demand: the first
    `fails` joins end as Ray's own client ends when the head's client server could not start this
    driver's session (ray-project/ray#63202), with Ray's exception and words."""

    __version__ = "2.60.0"

    def __init__(self, fails: int, error: str = "Starting Ray client server failed. See x.err") -> None:
        self.fails, self.error, self.joins, self.shutdowns = fails, error, 0, 0

    def init(self, **_: Any) -> None:
        self.joins += 1
        if self.joins <= self.fails:
            raise ConnectionAbortedError(
                f"Initialization failure from server:\nTraceback ...\nRuntimeError: {self.error}"
            )

    def shutdown(self) -> None:
        self.shutdowns += 1

    def remote(self, **_: Any) -> Any:
        return lambda f: f

    def cluster_resources(self) -> dict[str, float]:
        return {"CPU": 2.0}


def _join(fake: _FlakyRayClient, monkeypatch: pytest.MonkeyPatch) -> None:
    import asyncio
    import socket

    from mhrc.eval.cluster import RayExecutor

    monkeypatch.setitem(sys.modules, "ray", fake)
    with socket.create_server(("127.0.0.1", 0)) as head:  # something answers at the address
        address = f"ray://127.0.0.1:{head.getsockname()[1]}"

        async def join() -> None:
            async with RayExecutor(address):
                pass

        asyncio.run(join())


def test_a_ray_client_session_the_cluster_failed_to_start_is_joined_again(monkeypatch: pytest.MonkeyPatch) -> None:
    fake = _FlakyRayClient(fails=2)
    _join(fake, monkeypatch)
    assert fake.joins == 3 and fake.shutdowns == 3  # two failed joins undone, and the last one at the end


def test_joining_gives_up_after_three_failed_session_starts_and_other_failures_at_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from mhrc.run.config import ConfigError

    fake = _FlakyRayClient(fails=3)
    with pytest.raises(ConfigError, match=r"^--ray: could not join the Ray cluster at ray://.*client server failed"):
        _join(fake, monkeypatch)
    assert fake.joins == 3
    refused = _FlakyRayClient(fails=1, error="Authentication failed")  # not a failed start: not tried again
    with pytest.raises(ConfigError, match="Authentication failed"):
        _join(refused, monkeypatch)
    assert refused.joins == 1
