"""hanging-disks: hang a disk with a central hole on the rod of a tilted stand.

Train and test seeds use disjoint colour sets (validation seeds use the training colours), so a
policy is tested on disk and stand colours it never saw.
"""

from __future__ import annotations

import math

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.sim import assets, shapes
from nerf_transporter.sim.tasks.base import (
    Task,
    Tolerance,
    flat_pose,
    sample_free_xy,
)
from nerf_transporter.splits import split_of_seed

TRAIN_COLORS = ("red", "blue", "yellow", "brown", "cyan")
TEST_COLORS = ("orange", "purple", "pink", "white", "green")
TARGET_REGION = ((0.3, 0.66), (-0.35, 0.35))
OBJECT_REGION = ((0.3, 0.7), (-0.4, 0.4))
GAP = 0.01


def colors_for_split(split: str) -> tuple[str, ...]:
    """Colour names of a seed split: test seeds use colours no training seed uses."""
    return TEST_COLORS if split == "test" else TRAIN_COLORS


class HangingDisks(Task):
    name = "hanging-disks"
    tolerance = Tolerance(position=0.02, tilt=math.radians(15))

    def build(self, env, rng: np.random.Generator) -> None:
        palette = colors_for_split(split_of_seed(env.np_random_seed))
        disk_color, stand_color = (palette[k] for k in rng.choice(len(palette), 2, replace=False))
        self.colors = {"disk": disk_color, "stand": stand_color}

        hang = (np.array([0.0, 0.0, shapes.hanging_height()]), np.array([0.0, 0.0, 0.0, 1.0]))
        pick_radius = (shapes.DISK_RADIUS + shapes.DISK_HOLE_RADIUS) / 2
        angles = np.linspace(0.0, 2 * math.pi, 8, endpoint=False)
        reach_points = np.column_stack(
            [
                pick_radius * np.cos(angles),
                pick_radius * np.sin(angles),
                np.full(len(angles), shapes.hanging_height() + shapes.DISK_THICKNESS / 2),
            ]
        )
        stand_points = np.concatenate(shapes.stand_pieces())
        stand_pose = self.sample_target_pose(env, rng, TARGET_REGION, stand_points, reach_points)
        footprint = shapes.STAND_RADIUS + GAP
        stand = shapes.stand_urdf(assets.COLORS[stand_color])
        self.target_ids = [assets.load(env.client, stand, stand_pose, fixed=True)]
        self.target_poses = [geometry.multiply_poses(stand_pose, hang)]

        xy = sample_free_xy(
            rng, shapes.DISK_RADIUS + GAP, [(stand_pose[0], footprint)], OBJECT_REGION
        )
        disk = shapes.disk_urdf(assets.COLORS[disk_color])
        pose = flat_pose(xy, shapes.DISK_THICKNESS / 2, self.sample_yaw(rng))
        self.object_id = assets.load(env.client, disk, pose)
