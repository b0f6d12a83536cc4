"""Fused top-down colour + height map from the RGB-D trio (the input of the heightmap baselines).

Every depth pixel is back-projected to the world with its camera's intrinsics and pose (OpenCV
camera frame, depth along the optical axis), points outside the workspace box are dropped, and each
image pixel keeps the highest point that falls into it (Ravens' fusion). Pixels no camera sees stay
at height 0 with colour 0.
"""

from __future__ import annotations

import numpy as np

from nerf_transporter import geometry as g


def back_project(depth: np.ndarray, intrinsics: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    """Depth [H, W] (metres along the optical axis) -> world points [H, W, 3]."""
    rows, cols = depth.shape
    v, u = np.meshgrid(
        np.arange(rows, dtype=np.float64), np.arange(cols, dtype=np.float64), indexing="ij"
    )
    fx, fy = intrinsics[0, 0], intrinsics[1, 1]
    cx, cy = intrinsics[0, 2], intrinsics[1, 2]
    z = depth.astype(np.float64)
    camera = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], axis=-1)
    return camera @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]


def fuse_heightmap(
    rgb: np.ndarray,
    depth: np.ndarray,
    intrinsics: np.ndarray,
    cam_to_world: np.ndarray,
    pixel_size: float = g.PIXEL_SIZE,
) -> tuple[np.ndarray, np.ndarray]:
    """RGB-D captures ([N, H, W, 3] uint8, [N, H, W], [N, 3, 3], [N, 4, 4]) ->
    top-down (colour uint8 [rows, cols, 3], height float32 [rows, cols]) at `pixel_size`."""
    points = np.concatenate(
        [
            back_project(d, k, t).reshape(-1, 3)
            for d, k, t in zip(depth, intrinsics, cam_to_world, strict=True)
        ]
    )
    colours = np.asarray(rgb).reshape(-1, 3)
    valid = np.isfinite(points).all(axis=1) & (np.asarray(depth).reshape(-1) > 0)
    valid &= ((points >= g.BOUNDS[:, 0]) & (points < g.BOUNDS[:, 1])).all(axis=1)
    points, colours = points[valid], colours[valid]

    shape = g.image_shape(pixel_size)
    pixels = np.round(g.world_to_pixel(points, pixel_size)).astype(np.int64)
    inside = (pixels >= 0).all(axis=1) & (pixels[:, 0] < shape[0]) & (pixels[:, 1] < shape[1])
    pixels, points, colours = pixels[inside], points[inside], colours[inside]

    flat = pixels[:, 0] * shape[1] + pixels[:, 1]
    order = np.lexsort((points[:, 2], flat))  # by pixel, then by height
    flat, points, colours = flat[order], points[order], colours[order]
    highest = np.flatnonzero(np.r_[flat[1:] != flat[:-1], True])  # last (highest) point per pixel

    colour = np.zeros((shape[0] * shape[1], 3), dtype=np.uint8)
    height = np.zeros(shape[0] * shape[1], dtype=np.float32)
    colour[flat[highest]] = colours[highest]
    height[flat[highest]] = points[highest, 2] - g.BOUNDS[2, 0]
    return colour.reshape(*shape, 3), height.reshape(shape)


def heightmap_from_rgbd(
    rgbd: dict[str, np.ndarray], pixel_size: float = g.PIXEL_SIZE
) -> tuple[np.ndarray, np.ndarray]:
    """`fuse_heightmap` of an `rgbd` observation (or of an episode's rgbd.npz arrays)."""
    return fuse_heightmap(
        rgbd["rgb"], rgbd["depth"], rgbd["intrinsics"], rgbd["cam_to_world"], pixel_size
    )
