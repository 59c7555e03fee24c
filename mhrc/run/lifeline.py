"""Moved to `mhrc.core.lifeline` (a process utility every layer may use): these names stay here only
for the modules of mhrc.viewer and mhrc.eval that import them from here, until they import them
from core."""

from mhrc.core.lifeline import PARENT_ENV, PR_SET_PDEATHSIG, child_env, die_with_parent

__all__ = ["PARENT_ENV", "PR_SET_PDEATHSIG", "child_env", "die_with_parent"]
