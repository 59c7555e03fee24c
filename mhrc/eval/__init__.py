"""Evaluation: the grid, the engine and its executors (local pool, Ray), rows, summaries."""
