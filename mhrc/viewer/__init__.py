"""Seeing what happened: an episode's report (`mhrc show`), its video, its Rerun recording
(mhrc.viewer.rerun, also live while it runs), and the evaluation's HTML summary, all computed from
traces (plus the scene data)."""
