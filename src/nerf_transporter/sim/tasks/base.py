"""The Task base class: a task knows its assets, its oracle, its reward and its tolerances.

How to add a task family:

1. Subclass `Task` in a new module `sim/tasks/<name>.py`; set `name` (e.g. "hanging-disks"),
   `tolerance` (a `MatchTolerance`: the anchor's reward, which the table reports) and
   `strict_tolerance` (a `Tolerance`: the project's 6-DoF check, recorded as `strict_success`).
   Both are the success checks of docs/conventions.md, "Tasks, settings and success", kept only
   there.
2. Implement `build(env, rng)`: load the bodies with `assets.load(env.client, ...)` and set
   `self.object_id` (the body the robot moves), `self.target_poses` (the anchor's target poses the
   reward compares the object's pose with; any one counts), `self.strict_target_poses` (the same
   targets as the 3-D pose a seated object's origin rests at, for the strict check; default the
   `target_poses`) and optionally `self.target_ids` / `self.distractor_ids`. Use only `rng` for
   randomness so the episode is a function of the seed. Helpers: `sample_tilt`, `sample_yaw`,
   `sample_free_xy`, `sampling_region`, `sampling_radius`, `flat_pose`.
3. Override `max_targets` when the task has more than one target (it fixes the state length), and
   `oracle_target` / `pick_point` if the generic oracle does not fit.
4. Register the class with one line in `sim/tasks/__init__.py`, and add its name to
   `TASK_NAMES` in `sim/registration.py` (its gymnasium id; a test checks the two agree).

The generic oracle picks a random point on the visible top surface of the object (from an
orthographic top-down segmentation) and places at `target . inv(object) . pick`; the generic reward
compares the settled object pose with every target pose under `tolerance`, and with every strict
target pose under `strict_tolerance`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import cv2
import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim import assets
from nerf_transporter.sim.primitives import APPROACH, offset_along_z
from nerf_transporter.sim.robot import HOME_JOINTS, Robot

SETTINGS = ("normal", "challenging", "flat")
TRAIN_TILT = math.pi / 6
CHALLENGING_TILT = math.pi / 4
SUCTION_MARGIN = 0.008  # pick points stay this far inside the top surface (m)


# the errors `Tolerance.check` and `MatchTolerance.check` report: key, label, factor to the
# printed unit, printed unit
POSE_ERRORS = (
    ("position_error", "position", 100.0, "cm"),  # metres
    ("tilt_error", "tilt", 180.0 / math.pi, "deg"),  # radians
    ("yaw_error", "yaw", 180.0 / math.pi, "deg"),  # radians
)
POSE_ERROR_KEYS = tuple(key for key, *_ in POSE_ERRORS)
ROT_EPS = math.radians(15)  # the anchor's rotation limit (`Task.rot_eps` there)
MATCH_RP_FACTORS = (2.0, 1.5)  # match_rp: position and angle limits widened by these


def pose_error_text(errors: Mapping[str, Any]) -> str:
    """Why a pose missed its target, with the errors `errors` holds (those of `Tolerance.check`
    or `MatchTolerance.check`) in printed units."""
    parts = [
        f"{label} {errors[key] * scale:.1f} {unit}"
        for key, label, scale, unit in POSE_ERRORS
        if isinstance(errors.get(key), float | int)
    ]
    return "the object did not end at the target pose" + (f" ({', '.join(parts)})" if parts else "")


def _folded(angle: float, period: float) -> float:
    """|angle| modulo `period`, folded into [0, period / 2]."""
    angle = abs(angle) % period
    return min(angle, period - angle)


@dataclass(frozen=True)
class MatchTolerance:
    """The anchor's success check (Ravens' `Task.is_match`, docs/conventions.md): the x-y distance
    of the origins (m, never z) below `position`; the difference of the eulerXYZ yaws below `yaw`
    modulo `yaw_period` (`yaw` None: any yaw, the anchor's symmetry 0); with `roll_pitch`, the
    differences of the eulerXYZ rolls and pitches each below it (the anchor's `match_rp`)."""

    position: float
    yaw: float | None = ROT_EPS
    yaw_period: float = 2 * math.pi
    roll_pitch: float | None = None

    @classmethod
    def matching_roll_pitch(
        cls, pos_eps: float, yaw_free: bool = False, yaw_period: float = 2 * math.pi
    ) -> MatchTolerance:
        """The anchor's `match_rp` check from its `pos_eps`: every limit widened (x2, x1.5)."""
        position_factor, angle_factor = MATCH_RP_FACTORS
        angle = angle_factor * ROT_EPS
        return cls(position_factor * pos_eps, None if yaw_free else angle, yaw_period, angle)

    def check(self, pose: Pose, target: Pose) -> dict:
        """Errors of `pose` against `target` and whether all are within the limits (strictly)."""
        offset = np.asarray(pose[0], dtype=float)[:2] - np.asarray(target[0], dtype=float)[:2]
        position_error = geometry.norm(offset)
        euler = np.array(geometry.quat_to_euler(pose[1]))
        target_euler = np.array(geometry.quat_to_euler(target[1]))
        yaw_error = _folded(float(euler[2] - target_euler[2]), self.yaw_period)
        roll_pitch_error = float(np.abs(euler[:2] - target_euler[:2]).max())
        success = position_error < self.position
        success &= self.yaw is None or yaw_error < self.yaw
        success &= self.roll_pitch is None or roll_pitch_error < self.roll_pitch
        return {
            "success": bool(success),
            "position_error": position_error,
            "tilt_error": roll_pitch_error,
            "yaw_error": yaw_error,
        }


@dataclass(frozen=True)
class Tolerance:
    """The project's strict 6-DoF check on the settled pose: 3-D position (m), tilt (max |roll|,
    |pitch| of the relative rotation, rad; None: free), yaw (rad; None: free) modulo `yaw_period`
    (2 pi: no symmetry, 2 pi / k: k-fold)."""

    position: float
    tilt: float | None = None
    yaw: float | None = None
    yaw_period: float = 2 * math.pi

    def check(self, pose: Pose, target: Pose) -> dict:
        """Errors of `pose` relative to `target` and whether all are within tolerance."""
        position_error = geometry.norm(np.asarray(pose[0]) - np.asarray(target[0]))
        relative = geometry.matmul(
            geometry.quat_to_matrix(target[1]).T, geometry.quat_to_matrix(pose[1])
        )
        roll, pitch, yaw = geometry.matrix_to_euler(relative)
        tilt_error = max(abs(roll), abs(pitch))
        yaw_error = _folded(yaw, self.yaw_period)
        success = position_error <= self.position
        success &= self.tilt is None or tilt_error <= self.tilt
        success &= self.yaw is None or yaw_error <= self.yaw
        return {
            "success": bool(success),
            "position_error": position_error,
            "tilt_error": float(tilt_error),
            "yaw_error": float(yaw_error),
        }


def best_check(checks: Sequence[dict]) -> int:
    """Index of the check that succeeded, else of the one nearest in position."""
    return min(
        range(len(checks)), key=lambda k: (not checks[k]["success"], checks[k]["position_error"])
    )


class Scene(Protocol):
    """What a task needs of the environment: the simulator client, the arm (for reachability),
    the episode's seed (for its split) and a top-down segmentation (for the oracle's pick)."""

    client: Any
    robot: Robot
    np_random_seed: int

    def render_segmentation_top_down(self) -> tuple[np.ndarray, np.ndarray]: ...


class Task(ABC):
    """One task family in one setting (`normal`, `challenging` or `flat`)."""

    name: ClassVar[str]
    tolerance: ClassVar[MatchTolerance]
    strict_tolerance: ClassVar[Tolerance]
    max_targets: ClassVar[int] = 1
    max_steps: ClassVar[int] = 1

    def __init__(self, setting: str = "normal") -> None:
        if setting not in SETTINGS:
            raise ValueError(f"unknown setting {setting!r}; valid settings: {', '.join(SETTINGS)}")
        self.setting = setting
        self.object_id: int = -1
        self.target_poses: list[Pose] = []
        self.strict_target_poses: list[Pose] = []
        self.target_ids: list[int] = []
        self.distractor_ids: list[int] = []

    # -- to implement ------------------------------------------------------------------------------

    @abstractmethod
    def build(self, env: Scene, rng: np.random.Generator) -> None:
        """Load this episode's bodies and set `object_id` and `target_poses`."""

    # -- episode -----------------------------------------------------------------------------------

    def reset(self, env: Scene, rng: np.random.Generator) -> None:
        self.object_id, self.target_poses, self.strict_target_poses = -1, [], []
        self.target_ids, self.distractor_ids = [], []
        self.build(env, rng)
        if self.object_id < 0 or not self.target_poses:
            raise RuntimeError(f"task {self.name!r}: build() must set object_id and target_poses")
        if not self.strict_target_poses:
            self.strict_target_poses = list(self.target_poses)
        if len(self.strict_target_poses) != len(self.target_poses):
            raise RuntimeError(f"task {self.name!r}: one strict target pose per target pose")
        self._rng = rng

    def object_pose(self, env: Scene) -> Pose:
        return assets.get_pose(env.client, self.object_id)

    def state(self, env: Scene) -> np.ndarray:
        """Object pose then `max_targets` target poses (xyz + quat_xyzw each; missing ones zero)."""
        vector = np.zeros(7 * (1 + self.max_targets), dtype=np.float32)
        poses = [self.object_pose(env), *self.target_poses[: self.max_targets]]
        for k, (position, quat) in enumerate(poses):
            vector[7 * k : 7 * k + 7] = np.concatenate([position, quat])
        return vector

    @classmethod
    def state_dim(cls) -> int:
        return 7 * (1 + cls.max_targets)

    def reward(self, env: Scene) -> tuple[float, dict]:
        """1 when the object's pose matches any target pose within `tolerance` (the anchor's
        reward), else 0; the info holds that check's errors, `target_index`, and `strict_success`
        with `strict_errors`, the strict check against the strict target poses."""
        pose = self.object_pose(env)
        checks = [self.tolerance.check(pose, target) for target in self.target_poses]
        strict = [self.strict_tolerance.check(pose, t) for t in self.strict_target_poses]
        best, strict_best = best_check(checks), best_check(strict)
        info = dict(checks[best], target_index=best)
        info["strict_success"] = strict[strict_best]["success"]
        info["strict_errors"] = {
            key: value for key, value in strict[strict_best].items() if key != "success"
        }
        return float(info["success"]), info

    # -- oracle ------------------------------------------------------------------------------------

    def oracle(self, env: Scene) -> dict[str, Pose]:
        """Pick a random top-surface point, place so the object ends at its target pose."""
        object_pose = self.object_pose(env)
        pick = self.pick_point(env)
        target = self.oracle_target(env, object_pose)
        place = geometry.multiply_poses(target, geometry.invert_pose(object_pose), pick)
        return {"pick": pick, "place": place}

    def oracle_target(self, env: Scene, object_pose: Pose) -> Pose:
        """The target pose the oracle aims for (default: the first)."""
        return self.target_poses[0]

    def pick_point(self, env: Scene) -> Pose:
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
        """(roll, pitch) of a target: Normal both in [-pi/6, pi/6]; Challenging (the anchor's
        `-ood` classes) both in [-pi/4, pi/4], then one of them, chosen at random, replaced by
        +-[pi/6, pi/4]; flat (SE(2)) zero."""
        if self.setting == "flat":
            return 0.0, 0.0
        bound = CHALLENGING_TILT if self.setting == "challenging" else TRAIN_TILT
        roll, pitch = rng.uniform(-bound, bound, size=2)
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
        env: Scene,
        rng: np.random.Generator,
        region: tuple[tuple[float, float], tuple[float, float]],
        z: float,
        reach_points: np.ndarray,
        attempts: int = 100,
        taken: Sequence[tuple[np.ndarray, float]] = (),
        footprint: float = 0.0,
    ) -> Pose:
        """A target pose: tilt per setting, uniform yaw, uniform (x, y) in `region`, its origin at
        height `z` whatever the tilt (the anchor's: a steep target may dip into the table), and
        such that the arm can place at every one of `reach_points` [M, 3] (the object's pickable
        points, in the target frame). The position is redrawn for a drawn orientation first, so
        the tilt distribution is kept. With `taken` discs (centre, radius), the target's disc of
        radius `footprint` avoids them."""
        for _ in range(attempts):
            roll, pitch = self.sample_tilt(rng)
            rotation = geometry.euler_to_matrix(roll, pitch, self.sample_yaw(rng))
            quat = geometry.matrix_to_quat(rotation)
            for _ in range(attempts):
                xy = np.array([rng.uniform(*region[0]), rng.uniform(*region[1])])
                if any(geometry.norm(xy - np.asarray(c)[:2]) < footprint + r for c, r in taken):
                    continue
                pose = (np.array([xy[0], xy[1], z]), quat)
                if placeable(env, pose, reach_points):
                    return pose
        raise RuntimeError(f"task {self.name!r}: no reachable target pose in region {region}")


def placeable(env: Scene, target: Pose, reach_points: np.ndarray) -> bool:
    """Whether the arm reaches the place and pre-place poses of an object at `target` picked at
    any of `reach_points` (object frame); rotation about the approach axis is free (last joint)."""
    rotation = geometry.quat_to_matrix(target[1])
    for point in np.asarray(reach_points, dtype=float):
        place = (np.asarray(target[0]) + geometry.matmul(rotation, point), target[1])
        for pose in (place, offset_along_z(place, APPROACH)):
            if env.robot.solve_ik(pose, HOME_JOINTS) is None:
                return False
    return True


Region = tuple[tuple[float, float], tuple[float, float]]


def sampling_radius(size: Sequence[float]) -> float:
    """Half the diagonal of an object's x-y sampling `size`: how far the anchor's
    `get_random_pose` keeps its origin from what is already there (it erodes the free pixels by a
    square that wide)."""
    return math.hypot(size[0], size[1]) / 2


def sampling_region(size: Sequence[float]) -> Region:
    """Where the anchor's `get_random_pose` draws the origin of an object of x-y sampling `size` in
    an empty workspace: the workspace inset by `sampling_radius(size)` on every side."""
    margin = sampling_radius(size)
    (x0, x1), (y0, y1) = geometry.BOUNDS[:2]
    return (float(x0 + margin), float(x1 - margin)), (float(y0 + margin), float(y1 - margin))


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
        if all(geometry.norm(xy - np.asarray(c)[:2]) >= radius + r for c, r in taken):
            return xy
    raise RuntimeError(f"no free spot of radius {radius} m in region {region}")


def flat_pose(xy: Sequence[float], z: float, yaw: float) -> Pose:
    """Pose lying flat on the table at (x, y), body origin at height z."""
    return np.array([xy[0], xy[1], z], dtype=float), geometry.euler_to_quat(0.0, 0.0, yaw)
