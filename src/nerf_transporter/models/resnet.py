"""ResNet43_8s: the fully convolutional residual network of Transporter networks.

Bottleneck residual blocks, a stride-8 encoder and a bilinear-upsampling decoder, output at input
resolution. `width` is the channel count of the full-resolution stage (64 in Transporter networks);
the deeper stages use 2x, 4x and 8x that. No normalisation layers, so batch size 1 trains as well as
larger batches and DDP needs no synchronised statistics.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

STRIDE = 8
HEAD_CHANNELS = 16


class Bottleneck(nn.Module):
    """1x1 -> 3x3 -> 1x1 convolutions with a residual connection (projected when shapes change)."""

    def __init__(
        self,
        in_channels: int,
        channels: int,
        out_channels: int,
        stride: int = 1,
        activate: bool = True,
    ) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_channels, channels, 1, stride=stride)
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=1)
        self.conv3 = nn.Conv2d(channels, out_channels, 1)
        self.shortcut = (
            nn.Conv2d(in_channels, out_channels, 1, stride=stride)
            if stride != 1 or in_channels != out_channels
            else nn.Identity()
        )
        self.activate = activate

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.conv1(x), inplace=True)
        y = F.relu(self.conv2(y), inplace=True)
        y = self.conv3(y).add_(self.shortcut(x))
        return F.relu(y, inplace=True) if self.activate else y


def _stage(
    in_channels: int, channels: int, stride: int = 1, activate: bool = True
) -> nn.Sequential:
    """A projecting bottleneck followed by an identity bottleneck (two of the 43 layers' blocks)."""
    return nn.Sequential(
        Bottleneck(in_channels, channels, channels, stride=stride, activate=activate),
        Bottleneck(channels, channels, channels, activate=activate),
    )


class ResNet43_8s(nn.Module):  # noqa: N801 - the architecture's published name
    """FCN [B, in_channels, H, W] -> [B, out_channels, H, W] for any H, W (padded to a multiple of 8)."""

    def __init__(self, in_channels: int, out_channels: int, width: int = 64) -> None:
        super().__init__()
        w = width
        self.stem = nn.Conv2d(in_channels, w, 3, padding=1)
        self.encoder = nn.Sequential(
            _stage(w, w),
            _stage(w, 2 * w, stride=2),
            _stage(2 * w, 4 * w, stride=2),
            _stage(4 * w, 8 * w, stride=2),
        )
        self.decoder = nn.ModuleList([_stage(8 * w, 4 * w), _stage(4 * w, 2 * w), _stage(2 * w, w)])
        self.head = nn.Sequential(
            Bottleneck(w, HEAD_CHANNELS, out_channels, activate=False),
            Bottleneck(out_channels, HEAD_CHANNELS, out_channels, activate=False),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        height, width = x.shape[-2:]
        pad_h, pad_w = (-height) % STRIDE, (-width) % STRIDE
        if pad_h or pad_w:
            x = F.pad(x, (0, pad_w, 0, pad_h))
        if not torch.is_grad_enabled():
            # Channels-last convolutions run ~1.5x faster on CPU (oneDNN). Inference only: the CPU
            # backward pass on channels-last tensors corrupts the heap in torch 2.13 (reproduced with
            # a stride-2 1x1 convolution, 4 -> 8 channels, batch 8, one thread).
            x = x.contiguous(memory_format=torch.channels_last)
        y = self.encoder(F.relu(self.stem(x), inplace=True))
        for stage in self.decoder:
            y = F.interpolate(stage(y), scale_factor=2, mode="bilinear", align_corners=False)
        return self.head(y)[..., :height, :width]
