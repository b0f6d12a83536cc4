"""Attention (pick) model: one logit per pixel from a ResNet43 FCN."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from nerf_transporter.models.resnet import ResNet43_8s


class Attention(nn.Module):
    """[B, C, H, W] -> pick logits [B, H, W].

    With `square_fill` (one value per input channel) the image is first padded on both sides of
    its shorter axis to a square of that value, and the logits are cropped back to the image, as
    the attention of MIRA's and Ravens' code does (a 320 x 160 image becomes 320 x 320). Given
    the network-space value of the pixels the SE(2) augmentation leaves empty
    (`data.preprocess.empty_pixel_input`), a test image's borders then look as a training image's
    do: without it, an unaugmented image's table reaches the network's zero padding, which no
    augmented training image shows, and the pick can fall on the image's corner
    (docs/failures.md, "Picks on the image's corner").
    """

    def __init__(
        self, in_channels: int = 6, width: int = 64, square_fill: torch.Tensor | None = None
    ) -> None:
        super().__init__()
        self.net = ResNet43_8s(in_channels, 1, width)
        if square_fill is not None and tuple(square_fill.shape) != (in_channels,):
            raise ValueError(
                f"square_fill needs one value per input channel ({in_channels}), "
                f"got shape {tuple(square_fill.shape)}"
            )
        self.register_buffer("square_fill", square_fill, persistent=False)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        if self.square_fill is None:
            return self.net(image).squeeze(1)
        height, width = image.shape[-2:]
        side = max(height, width)
        top, left = (side - height) // 2, (side - width) // 2
        fill = self.square_fill.to(image.dtype)[:, None, None]
        square = fill.expand(*image.shape[:-2], side, side).clone()
        square[..., top : top + height, left : left + width] = image
        return self.net(square).squeeze(1)[..., top : top + height, left : left + width]


def pixel_cross_entropy(logits: torch.Tensor, pixel: torch.Tensor) -> torch.Tensor:
    """Softmax cross-entropy over all pixels of logits [B, H, W] against one-hot pixels [B, 2]."""
    index = pixel[:, 0].long() * logits.shape[-1] + pixel[:, 1].long()
    return F.cross_entropy(logits.flatten(1), index)
