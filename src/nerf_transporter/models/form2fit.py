"""Form2Fit: pick and place affordance FCNs plus a dense descriptor net for rotation matching.

The rotation is the bin whose rotated pick crop has descriptors closest to those of the place crop.
The descriptor net is trained with a contrastive loss: the labelled rotation pulls the two crops'
descriptors together, rotations more than one bin away are pushed at least `margin` apart.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from nerf_transporter import geometry as g
from nerf_transporter.models.attention import Attention
from nerf_transporter.models.resnet import ResNet43_8s
from nerf_transporter.models.transport import bin_angles, rotated_crops


class Form2FitNets(nn.Module):
    """The three Form2Fit networks over one heightmap image."""

    def __init__(
        self,
        in_channels: int = 6,
        n_rotations: int = g.N_ROTATIONS,
        crop_size: int = 64,
        width: int = 64,
        descriptor_dim: int = 16,
        square_fill: torch.Tensor | None = None,
    ) -> None:
        super().__init__()
        self.crop_size = crop_size
        self.pick = Attention(in_channels, width, square_fill)
        self.place = Attention(in_channels, width, square_fill)
        self.descriptor = ResNet43_8s(in_channels, descriptor_dim, width)
        self.register_buffer("angles", bin_angles(n_rotations), persistent=False)

    def rotation_distances(
        self, image: torch.Tensor, pick_pixel: torch.Tensor, place_pixel: torch.Tensor
    ) -> torch.Tensor:
        """Mean squared descriptor distance between rotated pick crop and place crop: [B, R]."""
        pick_crops = rotated_crops(image, pick_pixel, self.angles, self.crop_size)
        place_crop = rotated_crops(image, place_pixel, torch.zeros(1), self.crop_size)
        crops = torch.cat([pick_crops, place_crop], dim=1)
        descriptors = self.descriptor(crops.flatten(0, 1)).unflatten(0, crops.shape[:2])
        difference = descriptors[:, :-1] - descriptors[:, -1:]
        return difference.square().sum(2).mean((-2, -1))


def rotation_contrastive_loss(
    distances: torch.Tensor, rotation_bin: torch.Tensor, margin: float
) -> torch.Tensor:
    """Pull the labelled bin's distance to 0; push bins more than one bin away beyond `margin`."""
    n_rot = distances.shape[1]
    bins = torch.arange(n_rot, device=distances.device)
    gap = (bins[None] - rotation_bin[:, None].long()).abs()
    gap = torch.minimum(gap, n_rot - gap)
    positive = distances.gather(1, rotation_bin[:, None].long()).squeeze(1)
    far = (gap > 1).float()
    negative = (F.relu(margin - distances) * far).sum(1) / far.sum(1).clamp(min=1)
    return (positive + negative).mean()
