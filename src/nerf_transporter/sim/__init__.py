"""The PyBullet world: UR5e + suction, task families, camera rigs (see docs/interfaces.md)."""

from nerf_transporter.sim.env import RavensEnv, make_env
from nerf_transporter.sim.tasks import SETTINGS, TASKS

__all__ = ["SETTINGS", "TASKS", "RavensEnv", "make_env"]
