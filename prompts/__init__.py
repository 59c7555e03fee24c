"""Prompt templates, one set per robot kind: `<kind>_system.txt`, `<kind>_user.txt` and
`<kind>_hints.txt` (package data; mhrc.agents.crew fills them for a team)."""
