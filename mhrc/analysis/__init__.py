"""What a trace says about an episode, computed from the trace alone: the paper's metrics
(`metrics`), the team's share of the work and its redundant actions (`teamwork`), the failure
diagnostics (`diagnostics`) and partial observability checked over a whole trace (`observability`). Above the world and the agents' layer in name only: it reads the
wire's typed trace records (mhrc.core.records) and nothing of the world or the agents."""
