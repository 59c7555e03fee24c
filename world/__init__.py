"""World simulator: PyBullet scene, robots, skills, planners, tasks (installed as mhrc.world)."""

if __name__ != "mhrc.world":  # from the repository's root, `import world` would load these files a second time
    raise ImportError(f"import this folder as mhrc.world, not as {__name__!r} (the package mhrc reaches it by a link)")
