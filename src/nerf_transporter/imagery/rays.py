"""Ray generation: perspective rays of posed pinhole cameras and orthographic rays of a view.

Rays carry their interval inside the workspace box and their distance to the floor plane z = 0,
so the renderer can sample only inside the box and end every ray on the opaque floor.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from nerf_transporter import geometry

BOX_MIN = torch.tensor(geometry.BOUNDS[:, 0], dtype=torch.float32)
BOX_MAX = torch.tensor(geometry.BOUNDS[:, 1], dtype=torch.float32)

# Orthographic rays start at this coordinate along the view axis, above every point of the box.
ORTHO_START_HEIGHT = 1.0


@dataclass
class Rays:
    """A batch of rays with unit directions, their box interval [near, far] and floor distance."""

    origins: torch.Tensor  # [R, 3]
    directions: torch.Tensor  # [R, 3], unit length
    near: torch.Tensor  # [R] entry into the workspace box (equals far when the box is missed)
    far: torch.Tensor  # [R] exit from the workspace box
    floor: torch.Tensor  # [R] distance to the plane z = 0 (far when the ray never descends)

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, index: torch.Tensor | slice) -> Rays:
        return Rays(**{f.name: getattr(self, f.name)[index] for f in fields(self)})

    @property
    def exits_through_floor(self) -> torch.Tensor:
        """True where the ray crosses the box and leaves it through its bottom face."""
        descending = self.directions[:, 2] < -1e-9
        return descending & (self.far > self.near) & ((self.floor - self.far).abs() <= 1e-5)


def _safe(directions: torch.Tensor) -> torch.Tensor:
    return torch.where(directions.abs() < 1e-9, torch.full_like(directions, 1e-9), directions)


def box_interval(
    origins: torch.Tensor, directions: torch.Tensor, low: torch.Tensor, high: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Slab test: distances (entry >= 0, exit) of rays through an axis-aligned box; exit <= entry on a miss."""
    safe = _safe(directions)
    t_low = (low - origins) / safe
    t_high = (high - origins) / safe
    entry = torch.minimum(t_low, t_high).amax(dim=-1).clamp(min=0.0)
    return entry, torch.maximum(t_low, t_high).amin(dim=-1)


def make_rays(origins: torch.Tensor, directions: torch.Tensor) -> Rays:
    """Intersect rays with the workspace box and with the floor plane."""
    directions = directions / directions.norm(dim=-1, keepdim=True)
    entry, exit_ = box_interval(
        origins, directions, BOX_MIN.to(origins.device), BOX_MAX.to(origins.device)
    )
    safe = _safe(directions)
    descending = directions[:, 2] < -1e-9
    floor = torch.where(descending, -origins[:, 2] / safe[:, 2], exit_.clamp(min=0.0))
    hit = exit_ > entry
    far = torch.where(hit, exit_, floor)
    near = torch.where(hit, entry, floor)
    return Rays(origins, directions, near, far, floor)


def perspective_rays(
    intrinsics: torch.Tensor,
    cam_to_world: torch.Tensor,
    camera: torch.Tensor,
    rows: torch.Tensor,
    cols: torch.Tensor,
) -> Rays:
    """Rays through pixel centres (row, col) of cameras `camera` (OpenCV frame: x right, y down, z forward).

    intrinsics [N, 3, 3] and cam_to_world [N, 4, 4] are per camera; pixel (row, col) is at image
    coordinates (u, v) = (col, row), the OpenCV convention for pixel centres.
    """
    k = intrinsics[camera]
    u = cols.to(k.dtype)
    v = rows.to(k.dtype)
    x = (u - k[:, 0, 2] - k[:, 0, 1] * (v - k[:, 1, 2]) / k[:, 1, 1]) / k[:, 0, 0]
    y = (v - k[:, 1, 2]) / k[:, 1, 1]
    local = torch.stack([x, y, torch.ones_like(x)], dim=-1)
    pose = cam_to_world[camera]
    directions = torch.einsum("rij,rj->ri", pose[:, :3, :3], local)
    return make_rays(pose[:, :3, 3].contiguous(), directions)


def view_pixel_grid(pixel_size: float = geometry.PIXEL_SIZE) -> np.ndarray:
    """(row, col) of every pixel of an orthographic image, shape [H, W, 2]."""
    rows, cols = geometry.image_shape(pixel_size)
    grid = np.stack(np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij"), axis=-1)
    return grid.astype(np.float64)


def orthographic_rays(
    roll: float, pitch: float, pixel_size: float = geometry.PIXEL_SIZE, device: str = "cpu"
) -> Rays:
    """Rays of view (roll, pitch), one per pixel in row-major order, along -z of the view frame.

    Pixel (i, j) of the view is the world line {c + R_v (P' - c)} with P' = (x_j, y_i, h) as in
    docs/conventions.md, "Views and the view grid"; the ray starts at h = ORTHO_START_HEIGHT, so
    the height of a point at distance t is ORTHO_START_HEIGHT - t.
    """
    rotation = geometry.tilt_matrix(roll, pitch)
    in_view = geometry.pixel_to_world(view_pixel_grid(pixel_size), ORTHO_START_HEIGHT, pixel_size)
    origins = geometry.view_to_world(in_view.reshape(-1, 3), rotation)
    direction = rotation @ np.array([0.0, 0.0, -1.0])
    origins_t = torch.as_tensor(origins, dtype=torch.float32, device=device)
    directions_t = torch.as_tensor(direction, dtype=torch.float32, device=device).expand_as(
        origins_t
    )
    return make_rays(origins_t, directions_t.contiguous())


def depth_to_height(depth: torch.Tensor) -> torch.Tensor:
    """Distance along an orthographic ray -> height along the view axis."""
    return ORTHO_START_HEIGHT - depth
