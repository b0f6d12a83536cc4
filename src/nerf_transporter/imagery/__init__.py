"""Mental imagery: a radiance field fitted to RGB views, rendered as orthographic colour + height views."""

from nerf_transporter.imagery.fit import (
    RENDER_OPTIONS,
    FittedScene,
    ImageryConfig,
    NonFiniteLossError,
    fit_scene,
    render_views,
    resolve_device,
)
from nerf_transporter.imagery.metrics import height_mae_mm, psnr

__all__ = [
    "FittedScene",
    "ImageryConfig",
    "NonFiniteLossError",
    "RENDER_OPTIONS",
    "fit_scene",
    "height_mae_mm",
    "psnr",
    "render_views",
    "resolve_device",
]
