"""Transporter-SE(3) regression heads: place z, roll and pitch at a chosen (rotation, pixel).

A key stream on the pick crop rotated by the chosen bin gives, per head, `n_features` kernels; a query
stream on the place image gives the matching feature window at the chosen pixel. Their
correlations form one feature vector per head, which a small MLP maps to the regressed value.
"""

from __future__ import annotations

import torch
from torch import nn

from nerf_transporter import geometry as g
from nerf_transporter.models.resnet import ResNet43_8s
from nerf_transporter.models.transport import bin_angles, rotated_crops

N_HEADS = 3  # z, roll, pitch


class PoseRegression(nn.Module):
    """(pick image, pick pixel, place image, place pixel, rotation bin) -> [B, 3] (z, roll, pitch)."""

    def __init__(
        self,
        in_channels: int = 6,
        n_rotations: int = g.N_ROTATIONS,
        crop_size: int = 64,
        width: int = 64,
        feature_channels: int = 3,
        n_features: int = 8,
        hidden: int = 32,
    ) -> None:
        super().__init__()
        self.crop_size = crop_size
        self.feature_channels = feature_channels
        self.n_features = n_features
        self.key = ResNet43_8s(in_channels, N_HEADS * n_features * feature_channels, width)
        self.query = ResNet43_8s(in_channels, N_HEADS * feature_channels, width)
        self.heads = nn.ModuleList(
            nn.Sequential(
                nn.Linear(n_features, hidden),
                nn.ReLU(),
                nn.Linear(hidden, hidden),
                nn.ReLU(),
                nn.Linear(hidden, 1),
            )
            for _ in range(N_HEADS)
        )
        self.register_buffer("angles", bin_angles(n_rotations), persistent=False)

    def forward(
        self,
        pick_image: torch.Tensor,
        pick_pixel: torch.Tensor,
        place_image: torch.Tensor,
        place_pixel: torch.Tensor,
        rotation_bin: torch.Tensor,
    ) -> torch.Tensor:
        batch, size = pick_image.shape[0], self.crop_size
        angle = self.angles[rotation_bin.long()].unsqueeze(1)  # [B, 1]
        crop = rotated_crops(pick_image, pick_pixel, angle, size)[:, 0]
        kernels = self.key(crop).reshape(
            batch, N_HEADS, self.n_features, self.feature_channels, size, size
        )
        # The query window centred on the place pixel, zero outside the image (integer sampling).
        window = rotated_crops(self.query(place_image), place_pixel, torch.zeros(1), size)[:, 0]
        window = window.reshape(batch, N_HEADS, self.feature_channels, size, size)
        features = torch.einsum("bhncij,bhcij->bhn", kernels, window) / (size * size)
        return torch.cat([head(features[:, i]) for i, head in enumerate(self.heads)], dim=1)
