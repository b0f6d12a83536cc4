"""place-red-in-green: put the red cube into any of 1-3 tilted green bowls, among distractors."""

from __future__ import annotations

import math

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim import assets, shapes
from nerf_transporter.sim.tasks.base import (
    Task,
    Tolerance,
    box_corners,
    flat_pose,
    float_height,
    sample_free_xy,
)

MAX_GREEN_BOWLS = 3
DISTRACTORS = 10
DISTRACTOR_COLORS = ("blue", "yellow", "orange", "purple", "pink", "cyan", "brown", "white", "gray")
TARGET_REGION = ((0.3, 0.68), (-0.38, 0.38))
OBJECT_REGION = ((0.3, 0.7), (-0.4, 0.4))
DISTRACTOR_REGION = ((0.28, 0.72), (-0.44, 0.44))
GAP = 0.01  # free space kept between footprints (m)


def bowl_footprint() -> float:
    """Radius of the disc a bowl covers on the table, whatever its tilt."""
    return shapes.BOWL_RIM_RADIUS + shapes.BOWL_THICKNESS + GAP


def cube_footprint() -> float:
    return shapes.CUBE_SIZE / math.sqrt(2) + GAP


def cube_urdf(color: str) -> str:
    box = assets.Box((shapes.CUBE_SIZE,) * 3)
    return str(assets.write_urdf("cube", [box], color=assets.COLORS[color], mass=0.05))


class PlaceRedInGreen(Task):
    name = "place-red-in-green"
    tolerance = Tolerance(position=0.05)
    max_targets = MAX_GREEN_BOWLS

    def build(self, env, rng: np.random.Generator) -> None:
        client, taken = env.client, []
        bowl_points = np.concatenate(shapes.bowl_pieces())
        rest = (np.array([0.0, 0.0, shapes.bowl_rest_height()]), np.array([0.0, 0.0, 0.0, 1.0]))
        green = shapes.bowl_urdf(assets.COLORS["green"])
        half = shapes.CUBE_SIZE / 2
        reach_points = box_corners((half, half, 0.0), (0.0, 0.0, shapes.bowl_rest_height() + half))[
            ::2
        ]
        for _ in range(int(rng.integers(1, MAX_GREEN_BOWLS + 1))):
            pose = self.sample_target_pose(
                env,
                rng,
                TARGET_REGION,
                bowl_points,
                reach_points,
                taken=taken,
                footprint=bowl_footprint(),
            )
            taken.append((pose[0], bowl_footprint()))
            self.target_ids.append(assets.load(client, green, pose, fixed=True))
            self.target_poses.append(geometry.multiply_poses(pose, rest))

        xy = sample_free_xy(rng, cube_footprint(), taken, OBJECT_REGION)
        taken.append((xy, cube_footprint()))
        pose = flat_pose(xy, shapes.CUBE_SIZE / 2, self.sample_yaw(rng))
        self.object_id = assets.load(client, cube_urdf("red"), pose)
        self._add_distractors(env, rng, taken, bowl_points)

    def _add_distractors(self, env, rng, taken, bowl_points) -> None:
        """Ten bowls or blocks in other colours; a bowl that finds no room becomes a block."""
        for _ in range(DISTRACTORS):
            color = DISTRACTOR_COLORS[rng.integers(len(DISTRACTOR_COLORS))]
            as_bowl = rng.random() < 0.5
            if as_bowl:
                try:
                    xy = sample_free_xy(
                        rng, bowl_footprint(), taken, DISTRACTOR_REGION, attempts=200
                    )
                except RuntimeError:
                    as_bowl = False
            if as_bowl:
                roll, pitch = self.sample_tilt(rng)
                rotation = geometry.euler_to_matrix(roll, pitch, self.sample_yaw(rng))
                position = np.array([*xy, float_height(bowl_points, rotation)])
                pose = (position, geometry.matrix_to_quat(rotation))
                body = assets.load(
                    env.client, shapes.bowl_urdf(assets.COLORS[color]), pose, fixed=True
                )
                taken.append((xy, bowl_footprint()))
            else:
                xy = sample_free_xy(rng, cube_footprint(), taken, DISTRACTOR_REGION)
                pose = flat_pose(xy, shapes.CUBE_SIZE / 2, self.sample_yaw(rng))
                body = assets.load(env.client, cube_urdf(color), pose)
                taken.append((xy, cube_footprint()))
            self.distractor_ids.append(body)

    def oracle_target(self, env, object_pose: Pose) -> Pose:
        """A random green bowl; the cube keeps its yaw and takes the bowl's tilt."""
        position, quat = self.target_poses[int(self._rng.integers(len(self.target_poses)))]
        roll, pitch, _ = geometry.quat_to_euler(quat)
        rotation = geometry.tilt_matrix(roll, pitch) @ geometry.quat_to_matrix(object_pose[1])
        return position, geometry.matrix_to_quat(rotation)
