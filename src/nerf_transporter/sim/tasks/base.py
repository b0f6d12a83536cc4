"""The Task base class: a task knows its assets, its oracle, its reward and its tolerances.

How to add a task family:

1. Subclass `Task` in a new module `sim/tasks/<name>.py`; set `name` (e.g. "hanging-disks") and
   `tolerance` (a `Tolerance`, the success check of docs/conventions.md, "Tasks, settings and
   success", kept only there).
2. Implement `build(env, rng)`: load the bodies with `assets.load(env.client, ...)` and set
   `self.object_id` (the body the robot moves), `self.target_poses` (the poses the object must end
   at; any one counts) and optionally `self.target_ids` / `self.distractor_ids`. Use only `rng` for
   randomness so the episode is a function of the seed. Helpers: `sample_tilt`, `sample_yaw`,
   `float_height`, `sample_free_xy`, `flat_pose`.
3. Override `max_targets` when the task has more than one target (it fixes the state length), and
   `oracle_target` / `pick_point` if the generic oracle does not fit.
4. Register the class with one line in `sim/tasks/__init__.py`, and add its name to
   `TASK_NAMES` in `sim/registration.py` (its gymnasium id; a test checks the two agree).

The generic oracle picks a random point on the visible top surface of the object (from an
orthographic top-down segmentation) and places at `target . inv(object) . pick`; the generic reward
compares the settled object pose with every target pose under `tolerance`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import cv2
import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim import assets
from nerf_transporter.sim.primitives import APPROACH, offset_along_z
from nerf_transporter.sim.robot import HOME_JOINTS

if TYPE_CHECKING:
    from nerf_transporter.sim.env import RavensEnv

SETTINGS = ("normal", "challenging", "flat")
TRAIN_TILT = math.pi / 6
CHALLENGING_TILT = math.pi / 4
TABLE_CLEARANCE = 0.02  # lowest point of a tilted target above the table (m)
SUCTION_MARGIN = 0.008  # pick points stay this far inside the top surface (m)


# the errors `Tolerance.check` reports: key, label, factor to the printed unit, printed unit
POSE_ERRORS = (
    ("position_error", "position", 100.0, "cm"),  # metres
    ("tilt_error", "tilt", 180.0 / math.pi, "deg"),  # radians
    ("yaw_error", "yaw", 180.0 / math.pi, "deg"),  # radians
)
POSE_ERROR_KEYS = tuple(key for key, *_ in POSE_ERRORS)


def pose_error_text(errors: Mapping[str, Any]) -> str:
    """Why a pose missed its target, with the errors `errors` holds (those of `Tolerance.check`)
    in printed units."""
    parts = [
        f"{label} {errors[key] * scale:.1f} {unit}"
        for key, label, scale, unit in POSE_ERRORS
        if isinstance(errors.get(key), float | int)
    ]
    return "the object did not end at the target pose" + (f" ({', '.join(parts)})" if parts else "")


@dataclass(frozen=True)
class Tolerance:
    """Success tolerance on the settled pose: position (m), tilt (max |roll|, |pitch| in rad; None:
    free), yaw (rad; None: free) modulo `yaw_period` (2 pi: no symmetry, 2 pi / k: k-fold)."""

    position: float
    tilt: float | None = None
    yaw: float | None = None
    yaw_period: float = 2 * math.pi

    def check(self, pose: Pose, target: Pose) -> dict:
        """Errors of `pose` relative to `target` and whether all are within tolerance."""
        position_error = float(np.linalg.norm(np.asarray(pose[0]) - np.asarray(target[0])))
        relative = geometry.quat_to_matrix(target[1]).T @ geometry.quat_to_matrix(pose[1])
        roll, pitch, yaw = geometry.matrix_to_euler(relative)
        tilt_error = max(abs(roll), abs(pitch))
        yaw_error = yaw % self.yaw_period
        yaw_error = min(yaw_error, self.yaw_period - yaw_error)
        success = position_error <= self.position
        success &= self.tilt is None or tilt_error <= self.tilt
        success &= self.yaw is None or yaw_error <= self.yaw
        return {
            "success": bool(success),
            "position_error": position_error,
            "tilt_error": float(tilt_error),
            "yaw_error": float(yaw_error),
        }


class Task(ABC):
    """One task family in one setting (`normal`, `challenging` or `flat`)."""

    name: ClassVar[str]
    tolerance: ClassVar[Tolerance]
    max_targets: ClassVar[int] = 1
    max_steps: ClassVar[int] = 1

    def __init__(self, setting: str = "normal") -> None:
        if setting not in SETTINGS:
            raise ValueError(f"unknown setting {setting!r}; valid settings: {', '.join(SETTINGS)}")
        self.setting = setting
        self.object_id: int = -1
        self.target_poses: list[Pose] = []
        self.target_ids: list[int] = []
        self.distractor_ids: list[int] = []

    # -- to implement ------------------------------------------------------------------------------

    @abstractmethod
    def build(self, env: RavensEnv, rng: np.random.Generator) -> None:
        """Load this episode's bodies and set `object_id` and `target_poses`."""

    # -- episode -----------------------------------------------------------------------------------

    def reset(self, env: RavensEnv, rng: np.random.Generator) -> None:
        self.object_id, self.target_poses = -1, []
        self.target_ids, self.distractor_ids = [], []
        self.build(env, rng)
        if self.object_id < 0 or not self.target_poses:
            raise RuntimeError(f"task {self.name!r}: build() must set object_id and target_poses")
        self._rng = rng

    def object_pose(self, env: RavensEnv) -> Pose:
        return assets.get_pose(env.client, self.object_id)

    def state(self, env: RavensEnv) -> np.ndarray:
        """Object pose then `max_targets` target poses (xyz + quat_xyzw each; missing ones zero)."""
        vector = np.zeros(7 * (1 + self.max_targets), dtype=np.float32)
        poses = [self.object_pose(env), *self.target_poses[: self.max_targets]]
        for k, (position, quat) in enumerate(poses):
            vector[7 * k : 7 * k + 7] = np.concatenate([position, quat])
        return vector

    @classmethod
    def state_dim(cls) -> int:
        return 7 * (1 + cls.max_targets)

    def reward(self, env: RavensEnv) -> tuple[float, dict]:
        """1 when the object's pose matches any target pose within `tolerance`, else 0."""
        pose = self.object_pose(env)
        checks = [self.tolerance.check(pose, target) for target in self.target_poses]
        best = min(
            range(len(checks)),
            key=lambda k: (not checks[k]["success"], checks[k]["position_error"]),
        )
        info = dict(checks[best], target_index=best)
        return float(info["success"]), info

    # -- oracle ------------------------------------------------------------------------------------

    def oracle(self, env: RavensEnv) -> dict[str, Pose]:
        """Pick a random top-surface point, place so the object ends at its target pose."""
        object_pose = self.object_pose(env)
        pick = self.pick_point(env)
        target = self.oracle_target(env, object_pose)
        place = geometry.multiply_poses(target, geometry.invert_pose(object_pose), pick)
        return {"pick": pick, "place": place}

    def oracle_target(self, env: RavensEnv, object_pose: Pose) -> Pose:
        """The target pose the oracle aims for (default: the first)."""
        return self.target_poses[0]

    def pick_point(self, env: RavensEnv) -> Pose:
        """Upright pose at a random point of the object's visible top surface."""
        segmentation, height = env.render_segmentation_top_down()
        mask = (segmentation == self.object_id).astype(np.uint8)
        if not mask.any():
            raise RuntimeError(f"task {self.name!r}: the object is not visible from above")
        top = mask.astype(bool) & (height >= height[mask.astype(bool)].max() - 0.003)
        margin = max(1, int(round(SUCTION_MARGIN / geometry.PIXEL_SIZE)))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
        inner = cv2.erode(top.astype(np.uint8), kernel).astype(bool)
        candidates = np.argwhere(inner if inner.any() else top)
        row, col = candidates[self._rng.integers(len(candidates))]
        point = geometry.pixel_to_world(np.array([row, col]), height[row, col])
        return point, np.array([0.0, 0.0, 0.0, 1.0])

    # -- sampling helpers ----------------------------------------------------------------------------

    def sample_tilt(self, rng: np.random.Generator) -> tuple[float, float]:
        """(roll, pitch) of a target: Normal both in [-pi/6, pi/6]; Challenging one of them in
        +-[pi/6, pi/4] (the other as Normal); flat (SE(2)) zero."""
        if self.setting == "flat":
            return 0.0, 0.0
        roll, pitch = rng.uniform(-TRAIN_TILT, TRAIN_TILT, size=2)
        if self.setting == "challenging":
            outside = rng.choice([-1.0, 1.0]) * rng.uniform(TRAIN_TILT, CHALLENGING_TILT)
            if rng.integers(2) == 0:
                roll = outside
            else:
                pitch = outside
        return float(roll), float(pitch)

    @staticmethod
    def sample_yaw(rng: np.random.Generator) -> float:
        return float(rng.uniform(0.0, 2 * math.pi))

    def sample_target_pose(
        self,
        env: RavensEnv,
        rng: np.random.Generator,
        region: tuple[tuple[float, float], tuple[float, float]],
        body_points: np.ndarray,
        reach_points: np.ndarray,
        attempts: int = 100,
        taken: Sequence[tuple[np.ndarray, float]] = (),
        footprint: float = 0.0,
    ) -> Pose:
        """A target pose: tilt per setting, uniform yaw, uniform (x, y) in `region`, floating so the
        target's own `body_points` [N, 3] stay above the table, and such that the arm can place at
        every one of `reach_points` [M, 3] (the object's pickable points, in the object frame).
        The position is redrawn for a drawn orientation first, so the tilt distribution is kept.
        With `taken` discs (centre, radius), the target's disc of radius `footprint` avoids them."""
        for _ in range(attempts):
            roll, pitch = self.sample_tilt(rng)
            rotation = geometry.euler_to_matrix(roll, pitch, self.sample_yaw(rng))
            quat = geometry.matrix_to_quat(rotation)
            z = float_height(body_points, rotation)
            for _ in range(attempts):
                xy = np.array([rng.uniform(*region[0]), rng.uniform(*region[1])])
                if any(np.linalg.norm(xy - np.asarray(c)[:2]) < footprint + r for c, r in taken):
                    continue
                pose = (np.array([xy[0], xy[1], z]), quat)
                if placeable(env, pose, reach_points):
                    return pose
        raise RuntimeError(f"task {self.name!r}: no reachable target pose in region {region}")


def placeable(env: RavensEnv, target: Pose, reach_points: np.ndarray) -> bool:
    """Whether the arm reaches the place and pre-place poses of an object at `target` picked at
    any of `reach_points` (object frame); rotation about the approach axis is free (last joint)."""
    rotation = geometry.quat_to_matrix(target[1])
    for point in np.asarray(reach_points, dtype=float):
        place = (np.asarray(target[0]) + rotation @ point, target[1])
        for pose in (place, offset_along_z(place, APPROACH)):
            if env.robot.solve_ik(pose, HOME_JOINTS) is None:
                return False
    return True


def float_height(
    points: np.ndarray, rotation: np.ndarray, clearance: float = TABLE_CLEARANCE
) -> float:
    """Height of a body frame such that its local `points` [N, 3] rotated by `rotation` stay
    `clearance` above the table."""
    rotated = np.asarray(points, dtype=float) @ np.asarray(rotation).T
    return float(clearance - rotated[:, 2].min())


def box_corners(half_extents: Sequence[float], center: Sequence[float] = (0, 0, 0)) -> np.ndarray:
    """The 8 corners [8, 3] of an axis-aligned box."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    return np.asarray(center, dtype=float) + signs * np.asarray(half_extents, dtype=float)


def sample_free_xy(
    rng: np.random.Generator,
    radius: float,
    taken: Sequence[tuple[np.ndarray, float]],
    region: tuple[tuple[float, float], tuple[float, float]] = ((0.3, 0.7), (-0.4, 0.4)),
    attempts: int = 1000,
) -> np.ndarray:
    """A uniform (x, y) in `region` whose disc of `radius` overlaps none of the `taken` discs."""
    (x0, x1), (y0, y1) = region
    for _ in range(attempts):
        xy = np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])
        if all(np.linalg.norm(xy - np.asarray(c)[:2]) >= radius + r for c, r in taken):
            return xy
    raise RuntimeError(f"no free spot of radius {radius} m in region {region}")


def flat_pose(xy: Sequence[float], z: float, yaw: float) -> Pose:
    """Pose lying flat on the table at (x, y), body origin at height z."""
    return np.array([xy[0], xy[1], z], dtype=float), geometry.euler_to_quat(0.0, 0.0, yaw)
