"""Frames, rotations, poses and pixel <-> world maps shared by every part of the project.

Conventions (docs/conventions.md, "Frames and units" to "Views and the view grid"):

- Workspace x in [0.25, 0.75], y in [-0.5, 0.5], z in [0, 0.28] m; centre c = (0.5, 0, 0).
- Top-down image: 320 rows (y) x 160 columns (x), pixel size 0.003125 m;
  pixel (row i, col j) <-> x = 0.25 + j * s, y = -0.5 + i * s; height = z.
- Orientation: R = Ry(pitch) . Rx(roll) . Rz(yaw) ("eulerXYZ" of Ravens; "Orientation convention").
- View v is the rotation R_v = Ry(pitch_v) . Rx(roll_v); world point P is seen in view v at
  P' = R_v^T (P - c) + c, and P' is mapped to pixels and height as in the top-down image.
- Quaternions are (x, y, z, w), as PyBullet uses them. A pose is (xyz, quat_xyzw).

The world's arithmetic gives the same bits whatever BLAS kernel a CPU gets ("Arithmetic the same on
every CPU" below).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

PIXEL_SIZE = 0.003125
BOUNDS = np.array([[0.25, 0.75], [-0.5, 0.5], [0.0, 0.28]])
WORKSPACE_CENTER = np.array([0.5, 0.0, 0.0])
IMAGE_SHAPE = (320, 160)  # (rows along y, columns along x)

Pose = tuple[np.ndarray, np.ndarray]  # (xyz, quat_xyzw)

VIEW_GRIDS = {
    "normal": (7, math.pi / 6),
    "challenging": (11, math.pi / 4),
}


# ---------------------------------------------------------------------------------------------
# Arithmetic the same on every CPU
# ---------------------------------------------------------------------------------------------
# numpy hands `@`, `dot`, the norm of a vector and `linalg.inv` / `solve` to BLAS and LAPACK, whose
# kernels are chosen per CPU (another summation order, fused multiply-adds), and computes sin and
# cos of arrays with its own SIMD code on some CPUs. An episode's physics amplifies a last-bit
# difference in a commanded pose into another settled scene, so the world (this module and `sim/`)
# computes with these instead: elementwise products summed in a fixed order, and libm's sin and
# cos. tests/sim/test_trace.py plays the world's trace under another BLAS kernel to hold this.


def matmul(a: np.ndarray | Sequence, b: np.ndarray | Sequence) -> np.ndarray:
    """`a @ b` (numpy's rules for stacks of matrices and for vectors), each entry summed term by
    term in index order: the same bits whatever BLAS kernel the CPU gets."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.ndim == 0 or b.ndim == 0:
        raise ValueError("matmul: a scalar operand (use *)")
    left = a[None, :] if a.ndim == 1 else a
    right = b[:, None] if b.ndim == 1 else b
    if left.shape[-1] != right.shape[-2]:
        raise ValueError(f"matmul: shapes {a.shape} and {b.shape} do not align")
    result = left[..., :, 0, None] * right[..., 0, None, :]
    for k in range(1, left.shape[-1]):
        result = result + left[..., :, k, None] * right[..., k, None, :]
    if b.ndim == 1:
        result = result[..., 0]
    if a.ndim == 1:
        result = result[..., 0, :] if b.ndim > 1 else result[..., 0]
    return result


def norm(vector: np.ndarray | Sequence[float]) -> float:
    """Euclidean length of a vector, its squares summed in index order (see `matmul`)."""
    return math.sqrt(sum(float(v) * float(v) for v in np.ravel(vector)))


def invert_transform(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4 x 4 transform [R t; 0 1]: [R^T, -R^T t; 0 1]."""
    matrix = np.asarray(matrix, dtype=float)
    inverse = np.eye(4)
    inverse[:3, :3] = matrix[:3, :3].T
    inverse[:3, 3] = -matmul(matrix[:3, :3].T, matrix[:3, 3])
    return inverse


def cos_sin(angles: np.ndarray | Sequence[float]) -> np.ndarray:
    """(N, 2) array of (cos, sin) of each angle, from libm (see `matmul`)."""
    return np.array([[math.cos(a), math.sin(a)] for a in np.ravel(angles)]).reshape(-1, 2)


# ---------------------------------------------------------------------------------------------
# Rotations
# ---------------------------------------------------------------------------------------------


def rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def tilt_matrix(roll: float, pitch: float) -> np.ndarray:
    """R_tilt = Ry(pitch) . Rx(roll): the rotation of a view, or the tilt part of an orientation."""
    return matmul(rot_y(pitch), rot_x(roll))


def euler_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Ry(pitch) . Rx(roll) . Rz(yaw)."""
    return matmul(tilt_matrix(roll, pitch), rot_z(yaw))


def matrix_to_euler(matrix: np.ndarray) -> tuple[float, float, float]:
    """Inverse of `euler_to_matrix`: (roll, pitch, yaw) with roll in [-pi/2, pi/2]."""
    m = np.asarray(matrix, dtype=float)
    roll = -math.asin(float(np.clip(m[1, 2], -1.0, 1.0)))
    pitch = math.atan2(m[0, 2], m[2, 2])
    yaw_part = matmul(tilt_matrix(roll, pitch).T, m)
    yaw = math.atan2(yaw_part[1, 0], yaw_part[0, 0])
    return roll, pitch, yaw


def euler_to_quat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    return matrix_to_quat(euler_to_matrix(roll, pitch, yaw))


def quat_to_euler(quat_xyzw: Sequence[float]) -> tuple[float, float, float]:
    return matrix_to_euler(quat_to_matrix(quat_xyzw))


def quat_to_matrix(quat_xyzw: Sequence[float]) -> np.ndarray:
    return Rotation.from_quat(np.asarray(quat_xyzw, dtype=float)).as_matrix()


def matrix_to_quat(matrix: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(np.asarray(matrix, dtype=float)).as_quat()


def rotation_angle(rot_a: np.ndarray, rot_b: np.ndarray) -> float:
    """Angle in radians of the relative rotation between two rotation matrices."""
    cos = (np.trace(matmul(np.asarray(rot_a).T, rot_b)) - 1.0) / 2.0
    return math.acos(float(np.clip(cos, -1.0, 1.0)))


def wrap_angle(angle: float | np.ndarray) -> float | np.ndarray:
    """Wrap to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


# ---------------------------------------------------------------------------------------------
# Poses
# ---------------------------------------------------------------------------------------------


def pose_to_matrix(pose: Pose) -> np.ndarray:
    position, quat = pose
    matrix = np.eye(4)
    matrix[:3, :3] = quat_to_matrix(quat)
    matrix[:3, 3] = np.asarray(position, dtype=float)
    return matrix


def matrix_to_pose(matrix: np.ndarray) -> Pose:
    matrix = np.asarray(matrix, dtype=float)
    return matrix[:3, 3].copy(), matrix_to_quat(matrix[:3, :3])


def multiply_poses(*poses: Pose) -> Pose:
    """Compose poses left to right: multiply_poses(a, b) = a . b."""
    result = np.eye(4)
    for pose in poses:
        result = matmul(result, pose_to_matrix(pose))
    return matrix_to_pose(result)


def invert_pose(pose: Pose) -> Pose:
    return matrix_to_pose(invert_transform(pose_to_matrix(pose)))


# ---------------------------------------------------------------------------------------------
# Pixels of the top-down image and of tilted orthographic views
# ---------------------------------------------------------------------------------------------


def image_shape(pixel_size: float = PIXEL_SIZE) -> tuple[int, int]:
    """(rows, cols) of an image covering the workspace at `pixel_size` (320 x 160 by default)."""
    extent = BOUNDS[:2, 1] - BOUNDS[:2, 0]
    return int(round(extent[1] / pixel_size)), int(round(extent[0] / pixel_size))


def world_to_pixel(points: np.ndarray, pixel_size: float = PIXEL_SIZE) -> np.ndarray:
    """World xyz (..., 3) -> continuous (row, col) (..., 2) of the top-down image."""
    points = np.asarray(points, dtype=float)
    row = (points[..., 1] - BOUNDS[1, 0]) / pixel_size
    col = (points[..., 0] - BOUNDS[0, 0]) / pixel_size
    return np.stack([row, col], axis=-1)


def pixel_to_world(
    pixels: np.ndarray, height: np.ndarray | float, pixel_size: float = PIXEL_SIZE
) -> np.ndarray:
    """(row, col) (..., 2) and height (...) -> world xyz (..., 3) in the top-down frame."""
    pixels = np.asarray(pixels, dtype=float)
    x = BOUNDS[0, 0] + pixels[..., 1] * pixel_size
    y = BOUNDS[1, 0] + pixels[..., 0] * pixel_size
    z = np.broadcast_to(np.asarray(height, dtype=float), x.shape)
    return np.stack([x, y, z], axis=-1)


def world_to_view(points: np.ndarray, view_rotation: np.ndarray) -> np.ndarray:
    """P' = R_v^T (P - c) + c for points (..., 3)."""
    points = np.asarray(points, dtype=float)
    return matmul(points - WORKSPACE_CENTER, view_rotation) + WORKSPACE_CENTER


def view_to_world(points: np.ndarray, view_rotation: np.ndarray) -> np.ndarray:
    """P = c + R_v (P' - c) for points (..., 3)."""
    points = np.asarray(points, dtype=float)
    return matmul(points - WORKSPACE_CENTER, np.asarray(view_rotation).T) + WORKSPACE_CENTER


def world_to_view_pixel(
    points: np.ndarray, view_rotation: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World points -> ((row, col), height) in view v."""
    in_view = world_to_view(points, view_rotation)
    return world_to_pixel(in_view), in_view[..., 2]


def view_pixel_to_world(
    pixels: np.ndarray, height: np.ndarray | float, view_rotation: np.ndarray
) -> np.ndarray:
    """Pixel (row, col) and height in view v -> world xyz."""
    return view_to_world(pixel_to_world(pixels, height), view_rotation)


def pixel_inside_image(pixel: Sequence[float], shape: tuple[int, int] = IMAGE_SHAPE) -> bool:
    return 0 <= pixel[0] < shape[0] and 0 <= pixel[1] < shape[1]


# ---------------------------------------------------------------------------------------------
# View grid
# ---------------------------------------------------------------------------------------------


def view_grid(setting: str = "normal") -> np.ndarray:
    """(V, 2) array of (roll, pitch) per view, roll-major; the middle view is top-down.

    Normal: 7 x 7 over [-pi/6, pi/6]^2 (49 views). Challenging: 11 x 11 over [-pi/4, pi/4]^2.
    The SE(2) setting `flat` uses the Normal grid.
    """
    size, limit = VIEW_GRIDS["challenging" if setting == "challenging" else "normal"]
    angles = np.linspace(-limit, limit, size)
    rolls, pitches = np.meshgrid(angles, angles, indexing="ij")
    return np.stack([rolls.ravel(), pitches.ravel()], axis=-1)


def top_down_view_index(grid: np.ndarray) -> int:
    return int(np.argmin(np.abs(grid).sum(axis=1)))


def view_rotations(grid: np.ndarray) -> np.ndarray:
    """(V, 3, 3) view rotations R_v for a (V, 2) grid of (roll, pitch)."""
    return np.stack([tilt_matrix(roll, pitch) for roll, pitch in grid])


def nearest_view(roll: float, pitch: float, grid: np.ndarray) -> int:
    """Index of the grid view nearest to a (roll, pitch) tilt."""
    return int(np.argmin(np.hypot(grid[:, 0] - roll, grid[:, 1] - pitch)))


# ---------------------------------------------------------------------------------------------
# Rotation bins
# ---------------------------------------------------------------------------------------------


N_ROTATIONS = 36  # bins of the place yaw relative to the pick (10 degrees each)


def angle_to_bin(angle: float, n_rotations: int) -> int:
    """Nearest of `n_rotations` bins over [0, 2pi) (bin k is the angle 2 pi k / n)."""
    return int(round((float(angle) % (2 * math.pi)) / (2 * math.pi / n_rotations))) % n_rotations


def bin_to_angle(index: int, n_rotations: int) -> float:
    return 2 * math.pi * int(index) / n_rotations
