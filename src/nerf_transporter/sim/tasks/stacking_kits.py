"""stacking-kits: stack a flat shape on its dark copy lying on a tilted kit (the anchor's
`StackingKits`; Challenging its `StackingKitsOOD`).

The kit is the anchor's: a thin fixed plate, tilted, its origin at a fixed height. On it lies a
fixed dark copy of the object's own shape (a body of its own, as in the anchor) at a random yaw
and tilted with the kit; there is no cavity. The object lies flat on the table, clear of the kit,
and is to be stacked on top of the copy. The shape comes from the fixed catalogue of
`sim.shapes`: test seeds use shapes that no training seed uses.

Success is the anchor's `match_rp` check against the copy's pose: the object's origin (on its
bottom face) within 2 cm of the copy's in x-y, its roll, pitch and yaw (modulo the shape's
symmetry) within 22.5 deg. A stacked object's origin lies about 22 mm out along the kit's normal
from the copy's (its 2 cm thickness plus PyBullet's 1 mm collision margin of each mesh), which
the x-y check sees as 22 mm x sin(tilt) of offset: up to 17 mm of the 20 mm on Challenging tilts.
The strict check compares the object with the copy's pose moved out by one thickness.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim import assets, shapes
from nerf_transporter.sim.tasks.base import (
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

KIT_ORIGIN_Z = shapes.KIT_PLATE_SIZE[2] / 2 + 0.03  # m, at every tilt (the anchor's 0.0325)
TARGET_OFFSET = 0.0014  # m, the copy's origin above the kit's, in the kit's frame (the anchor's)
OBJECT_COLORS = ("purple", "blue", "green", "yellow", "red")  # the anchor's, one drawn per scene

# scene layout: the anchor draws each origin from the free workspace eroded by the diagonal of a
# sampling size, the kit first, then the object clear of the kit; here the kit's keep-out is the
# disc round its plate's corners
KIT_SAMPLING_SIZE = (0.28, 0.2)  # m (the anchor's)
OBJECT_SAMPLING_SIZE = (0.08, 0.08)  # m (the anchor's)
KIT_RADIUS = math.hypot(*shapes.KIT_PLATE_SIZE[:2]) / 2
OBJECT_RADIUS = sampling_radius(OBJECT_SAMPLING_SIZE)
KIT_REGION = sampling_region(KIT_SAMPLING_SIZE)
OBJECT_REGION = sampling_region(OBJECT_SAMPLING_SIZE)


def stacked_offset() -> Pose:
    """Pose, in the copy's frame, of an object stacked on it: one thickness out along its normal."""
    return np.array([0.0, 0.0, shapes.KIT_OBJECT_THICKNESS]), np.array([0.0, 0.0, 0.0, 1.0])


class StackingKits(Task):
    name = "stacking-kits"
    # the anchor's match_rp check from its pos_eps 0.01 m; `build` sets the shape's yaw period
    tolerance = MatchTolerance.matching_roll_pitch(0.01)
    # stricter: 3-D position of the stacked object within 1.5 cm, tilt and yaw within 15 deg
    strict_tolerance = Tolerance(position=0.015, tilt=math.radians(15), yaw=math.radians(15))

    def build(self, env: Scene, rng: np.random.Generator) -> None:
        names = shapes.kit_shapes_for_split(split_of_seed(env.np_random_seed))
        shape = shapes.KIT_SHAPES[names[rng.integers(len(names))]]
        self.shape = shape
        period = shape.yaw_period
        self.tolerance = dataclasses.replace(type(self).tolerance, yaw_period=period)
        self.strict_tolerance = dataclasses.replace(type(self).strict_tolerance, yaw_period=period)

        # the copy's yaw relative to the kit's: both uniform, as the anchor's absolute yaws are
        copy_in_kit = (
            np.array([0.0, 0.0, TARGET_OFFSET]),
            geometry.euler_to_quat(0.0, 0.0, self.sample_yaw(rng)),
        )
        # the arm must reach the top face of the object stacked on the copy (in the kit's frame)
        top = np.column_stack(
            [shape.outline, np.full(len(shape.outline), shapes.KIT_OBJECT_THICKNESS)]
        )
        position, quat = geometry.multiply_poses(copy_in_kit, stacked_offset())
        reach_points = geometry.matmul(top, geometry.quat_to_matrix(quat).T) + position
        kit_pose = self.sample_target_pose(env, rng, KIT_REGION, KIT_ORIGIN_Z, reach_points)
        target = geometry.multiply_poses(kit_pose, copy_in_kit)
        copy = shapes.kit_object_urdf(shape, shapes.KIT_TARGET_COLOR)
        self.target_ids = [
            assets.load(env.client, shapes.kit_plate_urdf(), kit_pose, fixed=True),
            assets.load(env.client, copy, target, fixed=True),
        ]
        self.target_poses = [target]
        self.strict_target_poses = [geometry.multiply_poses(target, stacked_offset())]

        xy = sample_free_xy(rng, OBJECT_RADIUS, [(kit_pose[0], KIT_RADIUS)], OBJECT_REGION)
        color = assets.COLORS[OBJECT_COLORS[rng.integers(len(OBJECT_COLORS))]]
        pose = flat_pose(xy, 0.0, self.sample_yaw(rng))  # resting on the table
        self.object_id = assets.load(env.client, shapes.kit_object_urdf(shape, color), pose)
