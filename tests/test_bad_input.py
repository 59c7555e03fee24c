"""Bad input on the command line (issue 20): one line naming the option, exit 2, nothing left
behind; and the certificates `--days` asks for. Every command runs for real, in a process of
its own, in an empty directory that must stay empty."""

from __future__ import annotations

import datetime
import resource
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from cryptography import x509

from mhrc.core import security


def _mhrc(*args: str, cwd: Path, preexec_fn: Callable[[], None] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mhrc", *args], cwd=cwd, capture_output=True, text=True, timeout=120, preexec_fn=preexec_fn)


def _refused(result: subprocess.CompletedProcess[str], option: str) -> str:
    """The command failed as bad input: exit 2, no traceback, one `Error:` line that names `option`."""
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and option in errors[0], result.stderr
    return errors[0]


# ------------------------------------------------------------------------- mhrc credentials
@pytest.mark.parametrize("days", ["inf", "1e9", "nan", "-1", "0", "36501"])
def test_credentials_refuses_days_that_make_no_certificate_and_writes_nothing(tmp_path: Path, days: str) -> None:
    line = _refused(_mhrc("credentials", "--out", "creds/run", "--days", days, cwd=tmp_path), "--days")
    assert "more than 0 and at most 36500" in line
    assert list(tmp_path.iterdir()) == []


def test_credentials_help_states_the_range_of_days(tmp_path: Path) -> None:
    out = _mhrc("credentials", "--help", cwd=tmp_path)
    assert out.returncode == 0 and "at most 36500" in " ".join(out.stdout.split())


def test_credentials_refuses_a_host_no_certificate_can_name_and_writes_nothing(tmp_path: Path) -> None:
    _refused(_mhrc("credentials", "--out", "creds", "--host", "wörld", cwd=tmp_path), "--host")
    assert list(tmp_path.iterdir()) == []


def test_credentials_that_cannot_be_written_leave_no_directory_behind(tmp_path: Path) -> None:
    """A write that fails half way (here: no file may grow past 0 bytes) takes back the
    directories the command created; a directory that was there before stays."""

    def no_file_may_grow() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (0, 0))

    _refused(_mhrc("credentials", "--out", "new/run", cwd=tmp_path, preexec_fn=no_file_may_grow), "--out")
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "mine").mkdir()
    _refused(_mhrc("credentials", "--out", "mine/run", cwd=tmp_path, preexec_fn=no_file_may_grow), "--out")
    assert [p.name for p in tmp_path.iterdir()] == ["mine"] and list((tmp_path / "mine").iterdir()) == []


@pytest.mark.parametrize("days", [0.001, 7.0])
def test_certificates_are_valid_until_now_plus_days(tmp_path: Path, days: float) -> None:
    """Not 5 minutes short of it (the start is backdated for clock skew, the end is not): a tiny
    --days is a short certificate, never one written already expired."""
    t0 = datetime.datetime.now(datetime.timezone.utc)
    security.make_run_credentials("days", ("alice",), tmp_path, days=days)
    t1 = datetime.datetime.now(datetime.timezone.utc)
    span = datetime.timedelta(days=days)
    for name in ("ca.pem", "world.pem"):
        cert = x509.load_pem_x509_certificate((tmp_path / name).read_bytes())
        # certificates hold whole seconds: the end may be up to a second before now + days
        assert t0 + span - datetime.timedelta(seconds=1) <= cert.not_valid_after_utc <= t1 + span, (name, cert.not_valid_after_utc, t0, t1)
        assert cert.not_valid_before_utc <= t0 - datetime.timedelta(minutes=4), name  # backdated for clock skew
        assert cert.not_valid_after_utc > t1, f"{name} was written already expired"


# ------------------------------------------------------------------------- --trace and eval --out
UNWRITABLE = "/dev/null/t.jsonl"  # under a file: no directory can be made there, whoever runs the test


@pytest.mark.parametrize(
    "args",
    [
        ["up", "--trace", UNWRITABLE],
        ["up", "--insecure", "--trace", UNWRITABLE],
        ["up", "--processes", "--trace", UNWRITABLE],
        ["world", "--insecure", "--trace", UNWRITABLE],
        ["up", "--trace", "."],  # a directory, not a file
    ],
    ids=["up", "up-insecure", "up-processes", "world", "a-directory"],
)
def test_a_trace_that_cannot_be_written_is_refused_before_anything_starts(tmp_path: Path, args: list[str]) -> None:
    line = _refused(_mhrc(*args, cwd=tmp_path), "--trace")
    assert "/dev/null" in line or "directory" in line
    assert list(tmp_path.iterdir()) == []  # no runs/, no credentials


def test_an_eval_out_that_cannot_be_created_is_refused_before_anything_starts(tmp_path: Path) -> None:
    line = _refused(_mhrc("eval", "--tasks", "pack_objects", "--scenes", "kitchen", "--objects", "3", "--workers", "1",
                          "--out", "/dev/null/x", cwd=tmp_path), "--out")  # fmt: skip
    assert "/dev/null is not a directory" in line
    assert list(tmp_path.iterdir()) == []
