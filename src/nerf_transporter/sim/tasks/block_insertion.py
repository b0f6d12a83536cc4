"""block-insertion: put an L-shaped block into the matching slot of a tilted L fixture."""

from __future__ import annotations

import math

import numpy as np

from nerf_transporter.sim import assets
from nerf_transporter.sim.tasks.base import (
    Task,
    Tolerance,
    box_corners,
    flat_pose,
    sample_free_xy,
)

ARM = 0.04  # width of each arm of the L (m)
SIZE = 0.1  # outer side of the L (m)
HEIGHT = 0.04
CLEARANCE = 0.004  # slot clearance per side (m)
WALL = 0.015  # fixture wall thickness (m)
SLOT_DEPTH = 0.02
FLOOR = 0.01
TARGET_REGION = ((0.3, 0.65), (-0.35, 0.35))
OBJECT_REGION = ((0.3, 0.7), (-0.4, 0.4))


def l_block_parts() -> list[assets.Box]:
    """The L block in its own frame (bounding-box centre): a bar along x and one along y."""
    half, h = SIZE / 2, HEIGHT / 2
    inner = -half + ARM
    return [
        assets.box_from_bounds((-half, half), (-half, inner), (-h, h)),
        assets.box_from_bounds((-half, inner), (inner, half), (-h, h)),
    ]


def fixture_parts() -> list[assets.Box]:
    """The fixture in the frame the block has when inserted: a floor and walls around an L slot.

    The floor is darker than the walls, as the floor of a real slot lies in shade: under the
    renderer's shadowless light a one-colour slot is invisible in RGB (its floor and the wall tops
    face up alike), and an RGB-only policy could not tell where or how the L points.
    """
    half, h, c, t = SIZE / 2, HEIGHT / 2, CLEARANCE, WALL
    inner = -half + ARM
    lo, hi = -half - c, half + c  # slot extent
    outer_lo, outer_hi = lo - t, hi + t
    walls_z = (-h, -h + SLOT_DEPTH)
    return [
        assets.box_from_bounds(
            (outer_lo, outer_hi),
            (outer_lo, outer_hi),
            (-h - FLOOR, -h),
            assets.COLORS["dark_brown"],
        ),
        assets.box_from_bounds((outer_lo, lo), (outer_lo, outer_hi), walls_z),
        assets.box_from_bounds((lo, outer_hi), (outer_lo, lo), walls_z),
        assets.box_from_bounds((hi, outer_hi), (lo, inner + c), walls_z),
        assets.box_from_bounds((lo, inner + c), (hi, outer_hi), walls_z),
        assets.box_from_bounds((inner + c, outer_hi), (inner + c, outer_hi), walls_z),
    ]


class BlockInsertion(Task):
    name = "block-insertion"
    tolerance = Tolerance(position=0.02, tilt=math.radians(15), yaw=math.radians(15))

    def build(self, env, rng: np.random.Generator) -> None:
        parts = fixture_parts()
        corners = np.concatenate([box_corners(np.divide(p.size, 2), p.position) for p in parts])
        half = SIZE / 2
        top_face = box_corners((half, half, 0.0), (0.0, 0.0, HEIGHT / 2))[::2]
        target = self.sample_target_pose(env, rng, TARGET_REGION, corners, top_face)
        position = target[0]
        fixture = assets.write_urdf("l_fixture", parts, color=assets.COLORS["brown"], mass=0.0)
        self.target_ids = [assets.load(env.client, fixture, target, fixed=True)]
        self.target_poses = [target]

        footprint = np.abs(corners[:, :2]).max() * math.sqrt(2)
        xy = sample_free_xy(rng, SIZE / math.sqrt(2), [(position, footprint)], OBJECT_REGION)
        block = assets.write_urdf("l_block", l_block_parts(), color=assets.COLORS["red"], mass=0.1)
        self.object_id = assets.load(
            env.client, block, flat_pose(xy, HEIGHT / 2, self.sample_yaw(rng))
        )
