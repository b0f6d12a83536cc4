"""An analytic scene for tests and demos: coloured boxes on a checkered floor, ray-cast exactly.

It gives perspective RGB images from a camera ring (OpenCV poses) and the exact orthographic colour
and height of any view, without the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from nerf_transporter import geometry
from nerf_transporter.imagery.rays import (
    Rays,
    depth_to_height,
    orthographic_rays,
    perspective_rays,
)

LIGHT = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
FLOOR_COLOURS = ((0.55, 0.5, 0.45), (0.3, 0.32, 0.36))
CHECKER = 0.04  # floor square edge (m)


@dataclass(frozen=True)
class Box:
    centre: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    colour: tuple[float, float, float]


def _shade(normal: torch.Tensor) -> torch.Tensor:
    light = torch.as_tensor(LIGHT, dtype=normal.dtype, device=normal.device)
    return 0.55 + 0.45 * (normal @ light).clamp(min=0.0)


def _hit_box(box: Box, rays: Rays) -> tuple[torch.Tensor, torch.Tensor]:
    """Distance to the box (inf where missed) and the world normal of the face hit."""
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    to_box = torch.tensor([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float32)
    centre = torch.tensor(box.centre, dtype=torch.float32)
    half = torch.tensor(box.size, dtype=torch.float32) / 2
    origins = (rays.origins - centre) @ to_box.T
    directions = rays.directions @ to_box.T
    safe = torch.where(directions.abs() < 1e-9, torch.full_like(directions, 1e-9), directions)
    t_low, t_high = (-half - origins) / safe, (half - origins) / safe
    t_near = torch.minimum(t_low, t_high)
    entry, axis = t_near.max(dim=-1)
    exit_ = torch.maximum(t_low, t_high).amin(dim=-1)
    hit = (exit_ >= entry) & (entry > 0)
    local_normal = torch.zeros_like(origins)
    local_normal.scatter_(1, axis[:, None], -torch.sign(safe.gather(1, axis[:, None])))
    return torch.where(hit, entry, torch.inf), local_normal @ to_box


def _floor_colour(points: torch.Tensor) -> torch.Tensor:
    cells = torch.floor(points[:, 0] / CHECKER) + torch.floor(points[:, 1] / CHECKER)
    odd = (cells.remainder(2) == 1)[:, None]
    return torch.where(
        odd, torch.tensor(FLOOR_COLOURS[1]), torch.tensor(FLOOR_COLOURS[0])
    ) * _shade(torch.tensor([[0.0, 0.0, 1.0]]))


@dataclass(frozen=True)
class SyntheticScene:
    boxes: tuple[Box, ...]

    def trace(self, rays: Rays) -> tuple[torch.Tensor, torch.Tensor]:
        """Colour [R, 3] in [0, 1] and distance [R] of the first surface (boxes or the floor)."""
        distance = rays.floor.clone()
        colour = _floor_colour(rays.origins + distance[:, None] * rays.directions)
        for box in self.boxes:
            t, normal = _hit_box(box, rays)
            closer = t < distance
            distance = torch.where(closer, t, distance)
            box_colour = torch.tensor(box.colour) * _shade(normal)[:, None]
            colour = torch.where(closer[:, None], box_colour, colour)
        return colour, distance

    def images(
        self, intrinsics: np.ndarray, cam_to_world: np.ndarray, shape: tuple[int, int]
    ) -> np.ndarray:
        """Perspective RGB uint8 [N, H, W, 3] of cameras (OpenCV intrinsics and poses)."""
        height, width = shape
        k = torch.as_tensor(intrinsics, dtype=torch.float32)
        poses = torch.as_tensor(cam_to_world, dtype=torch.float32)
        rows, cols = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
        out = []
        for camera in range(len(k)):
            ids = torch.full((height * width,), camera)
            rays = perspective_rays(k, poses, ids, rows.reshape(-1), cols.reshape(-1))
            colour, _ = self.trace(rays)
            out.append(_to_uint8(colour).view(height, width, 3))
        return torch.stack(out).numpy()

    def orthographic(
        self, roll: float, pitch: float, pixel_size: float = geometry.PIXEL_SIZE
    ) -> tuple[np.ndarray, np.ndarray]:
        """Exact colour uint8 [H, W, 3] and height float32 [H, W] of view (roll, pitch)."""
        rows, cols = geometry.image_shape(pixel_size)
        colour, distance = self.trace(orthographic_rays(roll, pitch, pixel_size))
        height = depth_to_height(distance)
        return _to_uint8(colour).view(rows, cols, 3).numpy(), height.view(rows, cols).numpy()


def _to_uint8(colour: torch.Tensor) -> torch.Tensor:
    return colour.clamp(0.0, 1.0).mul(255.0).round().to(torch.uint8)


def random_scene(seed: int, count: int = 4) -> SyntheticScene:
    """`count` boxes of random size, yaw and saturated colour inside the workspace."""
    rng = np.random.default_rng(seed)
    boxes = []
    for _ in range(count):
        size = rng.uniform([0.03, 0.03, 0.02], [0.1, 0.1, 0.08])
        centre = (rng.uniform(0.35, 0.65), rng.uniform(-0.35, 0.35), size[2] / 2)
        colour = rng.uniform(0.1, 1.0, 3)
        colour[rng.integers(3)] = 0.05
        boxes.append(Box(tuple(centre), tuple(size), float(rng.uniform(0, math.pi)), tuple(colour)))
    return SyntheticScene(tuple(boxes))


def ring_cameras(
    count: int,
    shape: tuple[int, int],
    focal: float,
    radius: float = 0.75,
    heights: tuple[float, float] = (0.45, 0.8),
    target: tuple[float, float, float] = (0.5, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Cameras on a ring around `target` alternating between two heights, looking at it.

    Returns OpenCV intrinsics [N, 3, 3] and cam_to_world [N, 4, 4] (float32).
    """
    height, width = shape
    k = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    goal = np.asarray(target, dtype=float)
    poses = []
    for index in range(count):
        angle = 2 * math.pi * index / count
        eye = goal + np.array(
            [radius * math.cos(angle), radius * math.sin(angle), heights[index % len(heights)]]
        )
        forward = (goal - eye) / np.linalg.norm(goal - eye)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        pose = np.eye(4)
        pose[:3, :3] = np.stack([right, down, forward], axis=1)
        pose[:3, 3] = eye
        poses.append(pose)
    return np.repeat(k[None], count, axis=0).astype(np.float32), np.stack(poses).astype(np.float32)
