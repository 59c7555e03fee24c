"""Where a recording's stream goes: an .rrd file, Rerun's web viewer served on 127.0.0.1, or the native
viewer. The viewers are the `rerun` binary that rerun-sdk ships, started by mhrc bound to loopback
and with Rerun's usage analytics off (they belong to the viewer: the SDK writing a file sends nothing).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

import rerun as rr
import rerun_cli

from mhrc.core.endpoints import free_port
from mhrc.run.lifeline import PR_SET_PDEATHSIG
from mhrc.viewer.rerun import Mode, Target

APPLICATION = "mhrc"
HOST = "127.0.0.1"
VIEWER_START = 30.0  # s a viewer has to listen


def rerun_binary() -> Path:
    """The `rerun` executable rerun-sdk installs (the CLI and the viewer)."""
    return Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")


def quiet_env() -> dict[str, str]:
    """The environment of a `rerun` process mhrc starts: Rerun's analytics off. Its pipeline
    (re_analytics) starts nothing where CI is set, as it does after `rerun analytics disable`;
    FORCE_RERUN_ANALYTICS, which would override both, is removed."""
    env = dict(os.environ)
    env.pop("FORCE_RERUN_ANALYTICS", None)
    env["CI"] = env.get("CI") or "1"
    env.setdefault("RUST_LOG", "warn")  # its own lines: warnings and errors only
    return env


def _die_with_us() -> None:
    """In the viewer's process, before it runs: SIGTERM when mhrc dies (Linux), so no viewer is left behind."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


@dataclass
class Stream:
    """An open recording stream and what serves it (a viewer process mhrc started), with the address
    a person opens (serve: the web viewer's page)."""

    rec: rr.RecordingStream
    target: Target
    address: str | None = None
    viewer: subprocess.Popen[bytes] | None = field(default=None, repr=False)

    def close(self) -> None:
        """Flush what was logged and close the sink (the file gets its footer); a viewer mhrc started stays
        up for the person looking at it: `stop_viewer` ends it."""
        self.rec.flush()
        self.rec.disconnect()

    def stop_viewer(self) -> None:
        if self.viewer is not None and self.viewer.poll() is None:
            self.viewer.terminate()
            try:
                self.viewer.wait(10.0)
            except subprocess.TimeoutExpired:
                self.viewer.kill()
                self.viewer.wait()


def _wait_port(port: int, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + VIEWER_START
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the rerun viewer exited with code {proc.returncode} before it listened")
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            if s.connect_ex((HOST, port)) == 0:
                return
        time.sleep(0.1)
    proc.terminate()
    raise RuntimeError(f"the rerun viewer did not listen on {HOST}:{port} within {VIEWER_START:.0f} s")


def open_stream(target: Target, recording_id: str) -> Stream:
    """A recording stream for `target`, its sink set (the blueprint follows with the data)."""
    rec = rr.RecordingStream(APPLICATION, recording_id=recording_id)
    if target.mode is Mode.FILE:
        assert target.path is not None
        target.path.parent.mkdir(parents=True, exist_ok=True)
        rec.save(target.path)
        return Stream(rec, target)
    grpc = free_port(HOST)
    if target.mode is Mode.SERVE:
        web = free_port(HOST)
        args = ["--serve-web", "--bind", HOST, "--port", str(grpc), "--web-viewer-port", str(web)]
    else:
        args = ["--bind", HOST, "--port", str(grpc), "--expect-data-soon", "--hide-welcome-screen"]
    viewer = subprocess.Popen(
        [str(rerun_binary()), *args], env=quiet_env(), stdout=subprocess.DEVNULL, preexec_fn=_die_with_us
    )
    _wait_port(grpc, viewer)
    url = f"rerun+http://{HOST}:{grpc}/proxy"
    rec.connect_grpc(url)
    address = f"http://{HOST}:{web}/?url={quote(url, safe='')}" if target.mode is Mode.SERVE else url
    return Stream(rec, target, address, viewer)
