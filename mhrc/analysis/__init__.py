"""What a trace says about an episode, computed from the trace alone: the paper's metrics
(`metrics`), the team's share of the work and its redundant actions (`teamwork`) and the failure
diagnostics (`diagnostics`). Above the world and the agents' layer in name only: it reads the
wire's typed trace records (mhrc.core.records) and nothing of the world or the agents."""
