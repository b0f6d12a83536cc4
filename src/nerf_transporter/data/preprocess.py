"""Network input: normalised RGB plus height repeated three times (the Ravens convention)."""

from __future__ import annotations

import numpy as np
import torch

COLOUR_MEAN = 0.18877631
COLOUR_STD = 0.07276466
HEIGHT_MEAN = 0.00509261
HEIGHT_STD = 0.00903967


def network_input(
    colour: np.ndarray | torch.Tensor, height: np.ndarray | torch.Tensor
) -> torch.Tensor:
    """uint8 colour [..., H, W, 3] and height in metres [..., H, W] -> float32 [..., 6, H, W]."""
    colour = torch.as_tensor(np.asarray(colour) if not torch.is_tensor(colour) else colour)
    height = torch.as_tensor(np.asarray(height) if not torch.is_tensor(height) else height)
    rgb = (colour.float() / 255.0 - COLOUR_MEAN) / COLOUR_STD
    depth = (height.float() - HEIGHT_MEAN) / HEIGHT_STD
    channels = torch.cat([rgb, depth.unsqueeze(-1).expand(*depth.shape, 3)], dim=-1)
    return channels.movedim(-1, -3).contiguous()


def empty_pixel_input() -> torch.Tensor:
    """[6] network input of a pixel the SE(2) augmentation leaves empty: colour 0, height 0
    (`data.augment.Se2Transform.apply_image` fills with 0 before normalisation)."""
    return network_input(np.zeros((1, 1, 3), np.uint8), np.zeros((1, 1), np.float32))[:, 0, 0]
