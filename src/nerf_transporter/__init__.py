"""nerf-transporter: 6-DoF pick-and-place from RGB images with NeRF mental imagery."""

__version__ = "0.1.0"
