"""The wire core every participant shares: protocol, keys, bus, security, trace, metrics.

It imports nothing of `mhrc.world`, `mhrc.agents` or the assembly above them (import-linter checks it).
"""
