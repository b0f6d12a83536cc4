"""Data augmentation, applied with OpenCV to every image of a sample: one random rotation +
translation of the image plane (SE(2)), applied identically to the poses its labels come from, and,
optionally, one random colour change (hue, saturation, value), which leaves the labels alone.

A transform rotates image content by `angle` about the image centre, counter-clockwise about the
view's z axis (rows run along y, columns along x), then shifts it by `shift` (rows, cols). For a
pose in a view frame (see `labels.pose_in_view`) this is the planar rigid motion
R' = Rz(angle) R, xy' = rotated and shifted xy, z unchanged; labels are then recomputed from the
moved poses, so the pixels follow the content and the rotation bin stays consistent:

- a flat place pose and the pick both turn by `angle`, so their yaw difference (the bin) is
  unchanged;
- a tilted place pose (the heightmap methods, or the residual tilt of a `mira` view) has its tilt
  axis turned by `angle`: its roll, pitch and yaw in that frame change together, and the bin moves
  by the yaw change of the place minus that of the pick, computed exactly from the moved pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.data.labels import ViewAction, continuous_pixel


@dataclass(frozen=True)
class Se2Transform:
    angle: float  # radians, counter-clockwise about the view's z axis
    shift: tuple[float, float]  # (rows, cols) applied after the rotation
    shape: tuple[int, int]  # (rows, cols) of the images it applies to

    @property
    def centre(self) -> np.ndarray:
        """(row, col) of the rotation centre (pixel centres sit at integer coordinates)."""
        return (np.asarray(self.shape, dtype=float) - 1.0) / 2.0

    def cv_matrix(self) -> np.ndarray:
        """2 x 3 forward map for `cv2.warpAffine` in OpenCV's (x = col, y = row) coordinates."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        rotation = np.array([[c, -s], [s, c]])
        centre_xy = self.centre[::-1]
        offset = centre_xy + np.asarray(self.shift, dtype=float)[::-1] - rotation @ centre_xy
        return np.hstack([rotation, offset[:, None]])

    def apply_pixels(self, pixels: np.ndarray) -> np.ndarray:
        """Continuous (row, col) pixels (..., 2) -> their position after the transform."""
        xy = np.asarray(pixels, dtype=float)[..., ::-1]
        matrix = self.cv_matrix()
        moved = xy @ matrix[:, :2].T + matrix[:, 2]
        return moved[..., ::-1]

    def apply_pose(self, pose: g.Pose, pixel_size: float) -> g.Pose:
        """Move a view-frame pose with the content of the image."""
        position, quat = pose
        pixel = continuous_pixel(position, pixel_size)
        moved = g.pixel_to_world(self.apply_pixels(pixel), position[2], pixel_size)
        rotation = g.rot_z(self.angle) @ g.quat_to_matrix(quat)
        return moved, g.matrix_to_quat(rotation)

    def apply_image(self, image: np.ndarray) -> np.ndarray:
        """Warp one image [H, W] or [H, W, C] (nearest neighbour, zeros outside)."""
        if image.shape[:2] != self.shape:
            raise ValueError(f"image of shape {image.shape[:2]} for a transform of {self.shape}")
        dtype = image.dtype
        source = image.astype(np.float32) if dtype == np.float16 else image
        warped = cv2.warpAffine(
            source,
            self.cv_matrix(),
            (self.shape[1], self.shape[0]),
            flags=cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        return warped.astype(dtype, copy=False).reshape(image.shape)

    def apply_images(self, images: np.ndarray) -> np.ndarray:
        """Warp a stack [N, H, W(, C)] of images."""
        return np.stack([self.apply_image(image) for image in images])


def identity_transform(shape: tuple[int, int]) -> Se2Transform:
    return Se2Transform(0.0, (0.0, 0.0), tuple(shape))


# How `sample_transform` draws a rotation and a shift:
# - "uniform": rotation uniform in +-max_angle, each shift uniform up to max_shift_fraction of its side;
# - "gaussian": rotation ~ N(0, 60 deg), each shift ~ N(0, (shorter side) / 6) pixels (MIRA's and
#   Ravens' draw: about 27 pixels at 320 x 160).
AUGMENT_DISTRIBUTIONS = ("uniform", "gaussian")
GAUSSIAN_ANGLE_STD = math.pi / 3
GAUSSIAN_SHIFT_STD_FRACTION = 1.0 / 6.0


def sample_transform(
    rng: np.random.Generator,
    shape: tuple[int, int],
    keep_inside: Sequence[np.ndarray],
    *,
    distribution: str = "uniform",
    max_angle: float = math.pi,
    max_shift_fraction: float = 0.5,
    margin: float = 1.0,
    attempts: int = 100,
) -> Se2Transform:
    """Random rotation and shift drawn from `distribution` (`AUGMENT_DISTRIBUTIONS`) that keeps
    every pixel of `keep_inside` at least `margin` pixels inside the image.

    Falls back to the identity if no such transform is found in `attempts` draws.
    """
    if distribution not in AUGMENT_DISTRIBUTIONS:
        raise ValueError(
            f"augmentation distribution must be one of {', '.join(AUGMENT_DISTRIBUTIONS)}, "
            f"got {distribution!r}"
        )
    rows, cols = shape
    points = np.asarray(keep_inside, dtype=float).reshape(-1, 2)
    for _ in range(attempts):
        if distribution == "uniform":
            angle = float(rng.uniform(-max_angle, max_angle))
            shift = (
                float(rng.uniform(-1.0, 1.0) * max_shift_fraction * rows),
                float(rng.uniform(-1.0, 1.0) * max_shift_fraction * cols),
            )
        else:
            angle = float(rng.normal(0.0, GAUSSIAN_ANGLE_STD))
            sigma = GAUSSIAN_SHIFT_STD_FRACTION * min(rows, cols)
            shift = (float(rng.normal(0.0, sigma)), float(rng.normal(0.0, sigma)))
        transform = Se2Transform(angle, shift, (rows, cols))
        moved = np.round(transform.apply_pixels(points))
        inside = (moved >= margin) & (moved <= np.array([rows, cols]) - 1 - margin)
        if inside.all():
            return transform
    return identity_transform(shape)


def augment_view_action(
    view_action: ViewAction, transform: Se2Transform, pixel_size: float
) -> ViewAction:
    """Apply the same image-plane transform to the pick (top-down) and place (view) poses."""
    return ViewAction(
        place_view=view_action.place_view,
        pick=transform.apply_pose(view_action.pick, pixel_size),
        place=transform.apply_pose(view_action.place, pixel_size),
    )


@dataclass(frozen=True)
class ColourJitter:
    """One colour change of every image of a sample: hue turned, saturation and value scaled.

    Grey pixels (no saturation) keep their hue-free colour under the turn, so a saturated object
    changes colour against a nearly grey table while the scene's layout and heights stay put.
    """

    hue_shift: float  # degrees added to the hue (HSV, hue in [0, 360))
    saturation_scale: float
    value_scale: float

    def apply(self, colour: np.ndarray) -> np.ndarray:
        """uint8 RGB images [..., H, W, 3] -> the same images with their colour changed."""
        if colour.dtype != np.uint8 or colour.shape[-1] != 3:
            raise ValueError(
                f"colour jitter takes uint8 RGB images, got {colour.dtype} {colour.shape}"
            )
        rgb = colour.reshape(-1, colour.shape[-2], 3).astype(np.float32) / 255.0
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        hsv[..., 0] = np.mod(hsv[..., 0] + self.hue_shift, 360.0)
        hsv[..., 1] = np.clip(hsv[..., 1] * self.saturation_scale, 0.0, 1.0)
        hsv[..., 2] = np.clip(hsv[..., 2] * self.value_scale, 0.0, 1.0)
        changed = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
        return np.round(np.clip(changed, 0.0, 1.0) * 255.0).astype(np.uint8).reshape(colour.shape)


def sample_colour_jitter(
    rng: np.random.Generator,
    *,
    saturation_range: tuple[float, float] = (0.2, 1.2),
    value_range: tuple[float, float] = (0.8, 1.2),
) -> ColourJitter:
    """Hue turned uniformly around the whole circle, saturation and value scaled uniformly in their
    ranges: every hue, and nearly grey or white versions of the colours, occur in training."""
    return ColourJitter(
        float(rng.uniform(0.0, 360.0)),
        float(rng.uniform(*saturation_range)),
        float(rng.uniform(*value_range)),
    )
