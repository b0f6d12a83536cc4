"""hanging-disks: hang a disk by its hole on the rod of a fixed, tilted stand (the anchor's
`HangingDisks` / `HangingDisksOOD`).

The anchor's reward (`match_rp`) compares the disk's origin with the middle of the rod in x-y
and its roll and pitch with the stand's; the strict check compares it in 3-D with a disk lying
on the stand's plate around the rod. Train and validation seeds draw the disk's colour from the
anchor's training colours, test seeds from evaluation colours no training seed uses; the stand
is always brown, as the anchor's.
"""

from __future__ import annotations

import math

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim import assets, shapes
from nerf_transporter.sim.tasks.base import (
    SUCTION_MARGIN,
    MatchTolerance,
    Scene,
    Task,
    Tolerance,
    flat_pose,
    sample_free_xy,
    sampling_radius,
    sampling_region,
)
from nerf_transporter.splits import split_of_seed

# the anchor's utils.TRAIN_COLORS
TRAIN_COLORS = ("blue", "red", "green", "yellow", "brown", "gray", "cyan")
# the anchor's utils.EVAL_COLORS, as its test seeds draw them: blue, red and green are training
# colours too, so 4 of the 7 test colours are unseen (docs/conventions.md)
TEST_COLORS = ("blue", "red", "green", "orange", "purple", "pink", "white")
STAND_COLOR = "brown"  # the anchor's stand.urdf rgba (0.612, 0.459, 0.373): its `brown`
POS_EPS = 0.01  # m, the anchor's `Task.pos_eps` (match_rp doubles it)
STAND_Z = 0.015  # m, the anchor's stand origin height: footprint height 0.01 / 2 + 0.01
STAND_FOOTPRINT = (0.12, 0.36)  # m, the anchor's `base_size` for sampling the stand
DISK_FOOTPRINT = (0.08, 0.08)  # m, the anchor's `size` for sampling the disk
DISK_YAW = math.pi  # the anchor loads the disk with quaternion (0, 0, 1, 0)
STRICT_TILT = math.radians(15)  # the project's strict limit on the disk's tilt off the plate
REACH_ANGLES = 8  # pick points per ring of the reach check (ours: the disk is round)


def colors_for_split(split: str) -> tuple[str, ...]:
    """The disk colours of a seed split: test seeds draw the anchor's evaluation colours."""
    return TEST_COLORS if split == "test" else TRAIN_COLORS


def pick_points(height: float) -> np.ndarray:
    """Points [M, 3] of the disk's top face where the oracle may pick it, for the disk's centre
    `height` above the frame's origin: two rings, SUCTION_MARGIN inside the hole and the rim."""
    radii = (shapes.DISK_HOLE_RADIUS + SUCTION_MARGIN, shapes.DISK_RADIUS - SUCTION_MARGIN)
    angles = 2 * math.pi * np.arange(REACH_ANGLES) / REACH_ANGLES
    top = height + shapes.DISK_THICKNESS / 2
    return np.array([[r * math.cos(a), r * math.sin(a), top] for r in radii for a in angles])


def along_rod(stand_pose: Pose, height: float) -> Pose:
    """The pose `height` up the rod of a stand at `stand_pose`, with the stand's orientation."""
    return geometry.multiply_poses(
        stand_pose, (np.array([0.0, 0.0, height]), np.array([0.0, 0.0, 0.0, 1.0]))
    )


class HangingDisks(Task):
    name = "hanging-disks"
    tolerance = MatchTolerance.matching_roll_pitch(POS_EPS, yaw_free=True)
    strict_tolerance = Tolerance(position=2 * POS_EPS, tilt=STRICT_TILT)

    def build(self, env: Scene, rng: np.random.Generator) -> None:
        disk_color = str(rng.choice(colors_for_split(split_of_seed(env.np_random_seed))))
        self.colors = {"disk": disk_color, "stand": STAND_COLOR}

        reach = pick_points(shapes.ROD_CENTRE_HEIGHT)
        stand_region = sampling_region(STAND_FOOTPRINT)
        stand_pose = self.sample_target_pose(env, rng, stand_region, STAND_Z, reach)
        stand = shapes.stand_urdf(assets.COLORS[STAND_COLOR])
        self.target_ids = [assets.load(env.client, stand, stand_pose, fixed=True)]
        self.target_poses = [along_rod(stand_pose, shapes.ROD_CENTRE_HEIGHT)]
        self.strict_target_poses = [along_rod(stand_pose, shapes.disk_rest_height())]

        pose = self._disk_pose(rng, stand_pose)
        disk = shapes.disk_urdf(assets.COLORS[disk_color])
        self.object_id = assets.load(env.client, disk, pose)

    def _disk_pose(self, rng: np.random.Generator, stand_pose: Pose) -> Pose:
        """The disk lying flat, clear of the stand's plate by the anchor's sampling margin (the
        arm reaches every pick point of the region but at its two far corners, 0.06% of it)."""
        plate = (stand_pose[0], math.hypot(*shapes.STAND_PLATE_SIZE[:2]) / 2)
        xy = sample_free_xy(
            rng, sampling_radius(DISK_FOOTPRINT), [plate], sampling_region(DISK_FOOTPRINT)
        )
        return flat_pose(xy, shapes.DISK_THICKNESS / 2, DISK_YAW)
