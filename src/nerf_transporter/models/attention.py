"""Attention (pick) model: one logit per pixel from a ResNet43 FCN."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from nerf_transporter.models.resnet import ResNet43_8s


class Attention(nn.Module):
    """[B, C, H, W] -> pick logits [B, H, W]."""

    def __init__(self, in_channels: int = 6, width: int = 64) -> None:
        super().__init__()
        self.net = ResNet43_8s(in_channels, 1, width)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.net(image).squeeze(1)


def pixel_cross_entropy(logits: torch.Tensor, pixel: torch.Tensor) -> torch.Tensor:
    """Softmax cross-entropy over all pixels of logits [B, H, W] against one-hot pixels [B, 2]."""
    index = pixel[:, 0].long() * logits.shape[-1] + pixel[:, 1].long()
    return F.cross_entropy(logits.flatten(1), index)
