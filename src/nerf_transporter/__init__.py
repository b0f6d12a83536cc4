"""nerf-transporter: 6-DoF pick-and-place from RGB images with NeRF mental imagery.

Importing the package registers the gymnasium ids `nerf_transporter/<task>-v0`
(`nerf_transporter.sim.registration`); PyBullet is imported only when an environment is made.
"""

from nerf_transporter.sim.registration import register_envs

__version__ = "0.1.0"

register_envs()
