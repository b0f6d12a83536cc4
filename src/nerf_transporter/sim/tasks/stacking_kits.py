"""stacking-kits: seat an extruded shape in the matching cavity of a tilted kit plate.

The shape is drawn from the fixed catalogue of `sim.shapes`: test seeds use shapes that no
training seed uses. Yaw is judged modulo the shape's rotational symmetry.
"""

from __future__ import annotations

import dataclasses
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

OBJECT_COLORS = ("red", "green", "blue", "yellow", "orange", "purple", "pink", "cyan")
TARGET_REGION = ((0.3, 0.66), (-0.35, 0.35))
OBJECT_REGION = ((0.3, 0.7), (-0.4, 0.4))
GAP = 0.01


class StackingKits(Task):
    name = "stacking-kits"
    tolerance = Tolerance(position=0.015, tilt=math.radians(15), yaw=math.radians(15))

    def build(self, env, rng: np.random.Generator) -> None:
        names = shapes.kit_shapes_for_split(split_of_seed(env.np_random_seed))
        shape = shapes.KIT_SHAPES[names[rng.integers(len(names))]]
        self.shape = shape
        self.tolerance = dataclasses.replace(type(self).tolerance, yaw_period=shape.yaw_period)

        floor, rim = shapes.kit_plate_pieces(shape)
        half = shapes.kit_half_size(shape)
        footprint = half * math.sqrt(2) + GAP
        seat = (np.array([0.0, 0.0, shapes.kit_rest_height()]), np.array([0.0, 0.0, 0.0, 1.0]))
        top = np.column_stack([shape.outline, np.full(len(shape.outline), shapes.KIT_THICKNESS)])
        plate_pose = self.sample_target_pose(
            env, rng, TARGET_REGION, np.concatenate(floor + rim), top
        )
        plate = shapes.kit_plate_urdf(shape, assets.COLORS["gray"], assets.COLORS["dark_gray"])
        self.target_ids = [assets.load(env.client, plate, plate_pose, fixed=True)]
        self.target_poses = [geometry.multiply_poses(plate_pose, seat)]

        radius = float(np.linalg.norm(shape.outline, axis=1).max()) + GAP
        xy = sample_free_xy(rng, radius, [(plate_pose[0], footprint)], OBJECT_REGION)
        color = assets.COLORS[OBJECT_COLORS[rng.integers(len(OBJECT_COLORS))]]
        pose = flat_pose(xy, shapes.KIT_THICKNESS / 2, self.sample_yaw(rng))
        self.object_id = assets.load(env.client, shapes.kit_object_urdf(shape, color), pose)
