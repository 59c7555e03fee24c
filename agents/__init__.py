"""Robot agents: observation, memory, policies (installed as mhrc.agents)."""
