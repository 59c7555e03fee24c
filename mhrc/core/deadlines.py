"""How long the world and an agent wait for each other while one attaches: part of the attach
protocol both sides keep (docs/protocol.md), here in the wire core so that the command line's
options take them as defaults without importing the bus."""

from __future__ import annotations

# s an agent waits, by default, for the world to answer its attach (at the start, or once it fell silent)
ATTACH_TIMEOUT = 30.0

# s an attached agent has to show its liveliness token. mhrc's agents declare it before they attach, so this only
# bounds how long an agent that never will can hold up an episode (once); it must never catch a live one: 30 s is
# as long as an agent itself waits for the world to answer its attach (RobotAgent.attach_timeout), what a loaded
# machine is granted everywhere else; a foreign agent that still declares its token after the attach reply has as long.
# The former 3 s, with the token declared after the reply, let a loaded 2-core machine's whole team go before it acted.
TOKEN_DEADLINE = 30.0
