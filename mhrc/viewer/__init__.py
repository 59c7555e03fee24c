"""Seeing what happened: an episode's report (`mhrc show`), its video, and the evaluation's
HTML summary, all computed from traces (plus the scene data)."""
