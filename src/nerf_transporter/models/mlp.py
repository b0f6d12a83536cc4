"""GT-State MLP: ground-truth state vector -> pick and place SE(3) poses.

Positions are regressed relative to the workspace centre in decimetres; rotations as their first two
matrix columns (the continuous 6-D representation), orthonormalised by Gram-Schmidt at inference.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

POSE_DIM = 9  # position (3) + two rotation columns (6)


class StateMLP(nn.Module):
    """[B, D] -> [B, 2, 9]: (pick, place) x (position, rotation columns 1 and 2)."""

    def __init__(self, state_dim: int, hidden: int = 128, layers: int = 3) -> None:
        super().__init__()
        blocks: list[nn.Module] = []
        size = state_dim
        for _ in range(layers):
            blocks += [nn.Linear(size, hidden), nn.ReLU()]
            size = hidden
        blocks.append(nn.Linear(size, 2 * POSE_DIM))
        self.net = nn.Sequential(*blocks)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        return self.net(state).unflatten(1, (2, POSE_DIM))


def rotation_from_columns(columns: torch.Tensor) -> torch.Tensor:
    """[..., 6] (two rotation matrix columns) -> the nearest rotation matrices [..., 3, 3]."""
    first = F.normalize(columns[..., :3], dim=-1)
    second = columns[..., 3:]
    second = F.normalize(second - (first * second).sum(-1, keepdim=True) * first, dim=-1)
    third = torch.cross(first, second, dim=-1)
    return torch.stack([first, second, third], dim=-1)


def columns_from_rotation(matrices: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3] -> [..., 6]: the first two columns."""
    return torch.cat([matrices[..., :, 0], matrices[..., :, 1]], dim=-1)


def quat_to_matrix(quat_xyzw: torch.Tensor) -> torch.Tensor:
    """Unit quaternions [..., 4] (x, y, z, w) -> rotation matrices [..., 3, 3]."""
    x, y, z, w = F.normalize(quat_xyzw, dim=-1).unbind(-1)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return torch.stack([torch.stack(row, dim=-1) for row in rows], dim=-2)
