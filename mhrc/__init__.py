"""mhrc: multi-heterogeneous robot collaboration with LLM agents over Zenoh."""
