"""An episode as a Rerun recording (`--rerun`): from a trace (`mhrc show`, `mhrc eval`) or live while it
runs (`mhrc up`), to an .rrd file, to Rerun's web viewer on loopback, or to the native viewer.

`rerun-sdk` is an optional extra (`pip install 'mhrc[rerun]'`); this module imports it only in
`require()` and in its submodules, so that the rest of mhrc runs without it. Rerun's own usage
analytics belong to its viewer, never to a recording written by the SDK; a viewer mhrc starts
(`--rerun spawn`) is started with them off (mhrc.viewer.rerun.sinks).
"""

from __future__ import annotations

import os
import stat
import sys
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from mhrc.core.writable import unwritable

INSTALL = "pip install 'mhrc[rerun]'"  # the one line that says how
RERUN_VERSION = "0.41"  # the rerun-sdk this code is written against (pyproject's extra)


class RerunProblem(StrEnum):
    MISSING = "missing"  # rerun-sdk is not installed
    UNWRITABLE = "unwritable"  # the recording's file cannot be written
    NOT_RRD = "not_rrd"  # a file that does not end in .rrd
    NO_DISPLAY = "no_display"  # spawn: the native viewer needs a display
    NOT_REGULAR = "not_regular"  # OUT.rrd is a symlink, a FIFO, a device or a socket: only a regular file is written


def not_regular(path: Path) -> str | None:
    """Why `path` is no place for a recording: a symlink (written through to its target), or
    something that exists and is not a regular file (a FIFO blocked the recording's open for good,
    a device took its bytes); None for a regular file or none at all. Reads the path itself
    (lstat), never what a link points to."""
    try:
        st = path.lstat()
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"{path} cannot be looked at: {exc.strerror or exc}"
    if stat.S_ISLNK(st.st_mode):
        return f"{path} is a symbolic link: give the recording's own path, not a link"
    if not stat.S_ISREG(st.st_mode):
        what = (
            "a FIFO"
            if stat.S_ISFIFO(st.st_mode)
            else "a device"
            if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode)
            else "a socket"
            if stat.S_ISSOCK(st.st_mode)
            else "a directory"
            if stat.S_ISDIR(st.st_mode)
            else "not a regular file"
        )
        return f"{path} is {what}: a recording is written to a regular file only"
    return None


class RerunError(ValueError):
    """`--rerun` cannot be done: `code` says why, the message what to do."""

    def __init__(self, code: RerunProblem, message: str) -> None:
        self.code = code
        super().__init__(message)


class Mode(StrEnum):
    FILE = "file"  # an .rrd file
    SERVE = "serve"  # Rerun's web viewer on 127.0.0.1
    SPAWN = "spawn"  # the native viewer, started by mhrc


@dataclass(frozen=True)
class Target:
    """Where a recording goes: `--rerun OUT.rrd`, `--rerun serve` or `--rerun spawn`."""

    mode: Mode
    path: Path | None = None


def require() -> None:
    """RerunError (MISSING, with the install line) when rerun-sdk cannot be imported."""
    try:
        import rerun  # noqa: F401
        import rerun_cli  # noqa: F401
    except ImportError:
        raise RerunError(RerunProblem.MISSING, f"--rerun needs rerun-sdk: {INSTALL}") from None


def parse_target(value: str, *, directory: bool = False) -> Target:
    """`serve`, `spawn` or a path (with `directory`: a directory for one recording per episode), checked
    before anything starts: rerun-sdk installed, the path writable."""
    require()
    if not directory and value == Mode.SPAWN.value and sys.platform.startswith("linux"):
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise RerunError(
                RerunProblem.NO_DISPLAY,
                "--rerun spawn: the native viewer needs a display (DISPLAY is not set); use --rerun serve or OUT.rrd",
            )
    if not directory and value in (Mode.SERVE.value, Mode.SPAWN.value):
        return Target(Mode(value))
    path = Path(value)
    if not directory and path.suffix != ".rrd":
        raise RerunError(RerunProblem.NOT_RRD, f"--rerun: {path} is not an .rrd file (or say serve, or spawn)")
    if not directory and (odd := not_regular(path)) is not None:
        raise RerunError(RerunProblem.NOT_REGULAR, f"--rerun: {odd}")
    problem = unwritable(path, directory=directory)
    if problem is not None:
        raise RerunError(RerunProblem.UNWRITABLE, f"--rerun: {problem}")
    return Target(Mode.FILE, path)
