"""The files of an evaluation directory, opened without following a symlink.

An evaluation directory may come from someone else (shared, unpacked, tampered): a symlink where
`episodes.jsonl`, `eval.json`, a summary or `traces/` belongs would make `--resume` or `mhrc
report` read or rewrite whatever it points to. Every file of the directory is read with
O_NOFOLLOW, appended to with O_NOFOLLOW, and written as a temporary file in the same directory
renamed over the name (a rename replaces a link, never its target); `refuse_links` checks the
whole directory once, before anything is written. A refusal is a ConfigError naming the file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from pathlib import Path

from mhrc.run.config import ConfigError

# every name an evaluation directory holds (and traces/, whose entries are checked too)
KNOWN = (
    "eval.json",
    "episodes.jsonl",
    "errors.jsonl",
    "summary.md",
    "summary.csv",
    "summary.html",
)
TRACES = "traces"


class LinkRefused(ConfigError):
    """A file of the evaluation directory is a symlink (or not a regular file)."""


def _refused(path: Path, what: str = "a symlink") -> LinkRefused:
    return LinkRefused(
        f"{path} is {what}; an evaluation directory's files are never followed (remove it or copy the file there)"
    )


def refuse_links(out: Path) -> None:
    """Raise LinkRefused if a file of the evaluation directory `out`, traces/ or a file in it is a
    symlink or no regular file (a directory, a FIFO, a device where a file belongs)."""
    for name in KNOWN:
        _regular_or_absent(out / name)
    traces = out / TRACES
    try:
        st = traces.lstat()
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        raise _refused(traces)
    if not stat.S_ISDIR(st.st_mode):
        raise _refused(traces, "not a directory")
    with os.scandir(traces) as entries:
        for entry in entries:
            if entry.is_symlink():
                raise _refused(traces / entry.name)


def _regular_or_absent(path: Path) -> None:
    try:
        st = path.lstat()
    except FileNotFoundError:
        return
    if stat.S_ISLNK(st.st_mode):
        raise _refused(path)
    if not stat.S_ISREG(st.st_mode):
        raise _refused(path, "not a regular file")


def read_bytes(path: Path) -> bytes | None:
    """The bytes of a file of the directory, None when it does not exist; LinkRefused for a symlink
    or anything but a regular file (a FIFO would block)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _refused(path) from None
        raise
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise _refused(path, "not a regular file")
        return f.read()


def write_text(path: Path, text: str) -> None:
    """Write `text` to `path` through a temporary file of its directory renamed over it: a symlink
    at `path` is refused, never written through, and a reader never sees half a file."""
    _regular_or_absent(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_bytes(path: Path, data: bytes) -> None:
    """`write_text` for bytes."""
    _regular_or_absent(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def append_text(path: Path, text: str) -> None:
    """Append `text` to `path` (created if absent), never through a symlink."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _refused(path) from None
        raise
    with os.fdopen(fd, "a", encoding="utf-8") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise _refused(path, "not a regular file")
        f.write(text)


def make_dirs(out: Path) -> None:
    """Create `out` and its traces/ (a symlinked traces/ is refused, not followed)."""
    out.mkdir(parents=True, exist_ok=True)
    traces = out / TRACES
    try:
        traces.mkdir()
    except FileExistsError:
        pass
    if traces.is_symlink() or not traces.is_dir():
        raise _refused(traces)


def inside(path: Path, root: Path) -> bool:
    """Whether `path`, resolved, lies inside `root`, resolved (a derived path must stay in its directory)."""
    try:
        path.resolve().relative_to(root.resolve())
    except ValueError:
        return False
    return True
