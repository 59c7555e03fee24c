"""The names the bus gives its participants other than the robots: no robot may take one.

A run's logins are the world's, one per robot and the observer's (mhrc.core.security); each
login's files are named after it (`world.json`, `observer.json`), and the router's access rules
give every robot a subject `s-<name>` and a policy `p-<name>` beside the shared ones. A robot
named like any of these took the world's login (`mhrc credentials --team world=...` handed robot
`world` the world's key) or repeated a rule's id (the router refused to start). Team validation
(mhrc.core.team) and the credentials (mhrc.core.security) refuse these names before anything is
written.
"""

from __future__ import annotations

__all__ = ["ACL_GROUPS", "OBSERVER", "RESERVED", "WORLD", "reserved_why"]

WORLD = "world"  # the world's login: its router, its certificate and key, the users' dictionary
OBSERVER = "observer"  # subscribes to everything of the run, publishes nothing (the recorder of `mhrc up --processes`)
ACL_GROUPS = ("robots", "visible")  # the router's shared subject `s-robots` and policy `p-visible`
RESERVED = frozenset({WORLD, OBSERVER, *ACL_GROUPS})


def reserved_why(name: str) -> str | None:
    """Why a robot may not be called `name` (one clause), or None when it may."""
    if name in (WORLD, OBSERVER):
        return f"{name!r} is the {name}'s own login on the bus"
    if name in ACL_GROUPS:
        return f"{name!r} names a group of the router's access rules"
    return None
