"""World simulator: PyBullet scene, robots, skills, planners, tasks (installed as mhrc.world)."""
