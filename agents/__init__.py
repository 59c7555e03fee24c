"""Robot agents: observation, memory, policies (installed as mhrc.agents)."""

if __name__ != "mhrc.agents":  # from the repository's root, `import agents` would load these files a second time
    raise ImportError(f"import this folder as mhrc.agents, not as {__name__!r} (the package mhrc reaches it by a link)")
