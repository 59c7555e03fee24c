"""Where a recording's stream goes: an .rrd file, Rerun's web viewer served on 127.0.0.1, or the native
viewer. The viewers are the `rerun` binary that rerun-sdk ships, started by mhrc bound to loopback,
dying with mhrc, and with Rerun's usage analytics off (they belong to the viewer: the SDK writing a
file or streaming to a viewer sends nothing).
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
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

import rerun as rr
import rerun_cli

from mhrc.core.endpoints import free_port
from mhrc.core.lifeline import PR_SET_PDEATHSIG
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


def die_with_us() -> None:
    """In a child's process, before it runs: SIGTERM when mhrc dies (Linux), so that none is left behind."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


@dataclass
class Viewer:
    """A viewer mhrc started (serve: the web viewer and its gRPC proxy; spawn: the native one): the URL a
    recording stream connects to, and the address a person opens."""

    process: subprocess.Popen[bytes]
    url: str
    address: str

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def start_viewer(target: Target) -> Viewer | None:
    """The viewer `target` asks for, listening on 127.0.0.1 (None for a file). RuntimeError if it does not start."""
    if target.mode is Mode.FILE:
        return None
    grpc = free_port(HOST)
    if target.mode is Mode.SERVE:
        web = free_port(HOST)
        args = ["--serve-web", "--bind", HOST, "--port", str(grpc), "--web-viewer-port", str(web)]
    else:
        args = ["--bind", HOST, "--port", str(grpc), "--expect-data-soon", "--hide-welcome-screen"]
    proc = subprocess.Popen(
        [str(rerun_binary()), *args], env=quiet_env(), stdout=subprocess.DEVNULL, preexec_fn=die_with_us
    )
    deadline = time.monotonic() + VIEWER_START
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the rerun viewer exited with code {proc.returncode} before it listened")
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            if s.connect_ex((HOST, grpc)) == 0:
                url = f"rerun+http://{HOST}:{grpc}/proxy"
                address = f"http://{HOST}:{web}/?url={quote(url, safe='')}" if target.mode is Mode.SERVE else url
                return Viewer(proc, url, address)
        time.sleep(0.1)
    proc.terminate()
    raise RuntimeError(f"the rerun viewer did not listen on {HOST}:{grpc} within {VIEWER_START:.0f} s")


def open_stream(recording_id: str, path: Path | None = None, url: str | None = None) -> rr.RecordingStream:
    """A recording stream saving to the .rrd `path`, or streaming to a viewer's `url`."""
    rec = rr.RecordingStream(APPLICATION, recording_id=recording_id)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        rec.save(path)
    else:
        rec.connect_grpc(url)
    return rec


def close_stream(rec: rr.RecordingStream) -> None:
    """Flush what was logged and close the sink (a file gets its footer)."""
    rec.flush()
    rec.disconnect()
