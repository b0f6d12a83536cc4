"""block-insertion: put an L-shaped block into a tilted L fixture (the anchor's
`BlockInsertionSixDof`; Challenging its `BlockInsertionSixDofOOD`).

The fixture is the anchor's: thin walls as tall as the block around two channels with 9 mm of
clearance per side, and no floor but a small pad under the corner of the L, so a seated block
stands on the pad and leans on the walls. The block comes first and the fixture is drawn clear of
it, as in the anchor. Success is the anchor's: the block's origin within 2 cm of the fixture's in
x-y and its yaw within 15 deg (the L has no symmetry); roll, pitch and height are not checked.

The renderer has no shadows, so walls of the table's colour would leave the slot invisible in
RGB: the walls are dark on the channel side and the pad is dark (colours only; the collision
shapes are the anchor's).
"""

from __future__ import annotations

import math

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim import assets
from nerf_transporter.sim.tasks.base import (
    MatchTolerance,
    Scene,
    Task,
    Tolerance,
    box_corners,
    flat_pose,
    sampling_region,
)

# the block (the anchor's ell.urdf): two boxes, one along x and one along y, overlapping in the
# corner square, which holds the origin
ARM_LENGTH = 0.08  # m, each box 0.08 x 0.03 x 0.04 (the anchor's)
ARM_WIDTH = 0.03  # m (the anchor's)
BLOCK_HEIGHT = 0.04  # m (the anchor's)
ARM_OFFSET = 0.025  # m, each box's centre from the origin along its arm (the anchor's)
BLOCK_MASS = 0.1  # kg (the anchor's)
FRICTION = 0.3  # lateral friction of the block and the fixture (the anchor's)
CENTER_OF_MASS = (0.0, 0.0, 0.0)  # both URDFs put the inertial origin at the link origin

# the fixture (the anchor's fixture.urdf), in the frame of the block it holds
CLEARANCE = 0.009  # m between a centred block and each wall (the anchor's 48 mm channels)
WALL_THICKNESS = 0.002  # m (the anchor's)
WALL_HEIGHT = BLOCK_HEIGHT  # m, centred on the origin like the block (the anchor's 0.04)
PAD_SIZE = (0.02, 0.02, 0.001)  # m, the only floor, under the corner square (the anchor's)
PAD_DEPTH = 0.02  # m, the pad's centre below the origin (the anchor's)
FIXTURE_Z = BLOCK_HEIGHT / 2 + 0.03  # m, the fixture origin's height at every tilt (the anchor's)
FIXTURE_MASS = 0.0  # a static body (the anchor's 0.1 kg on a fixed base acts the same)

# scene layout: the anchor draws both origins from the free workspace eroded by the diagonal of
# this size; the two bodies are kept apart by discs that hold them whole (the anchor's erosion
# keeps the origin 7.2 cm from the block, and a tilted fixture reaches 8.3 cm from its origin)
SAMPLING_SIZE = (0.1, 0.1, 0.04)  # m, the anchor's size of both bodies for `get_random_pose`
REGION = sampling_region(SAMPLING_SIZE)

# colours: the anchor's block is red; its fixture's light grey (0.73, 0.69, 0.67) is about the
# table's colour, so the walls here are mid grey outside and dark on the channel side
BLOCK_COLOR = assets.COLORS["red"]
WALL_COLOR = assets.COLORS["gray"]
SLOT_COLOR = assets.COLORS["dark_gray"]  # the channel side of the walls, and the pad


def block_outline() -> np.ndarray:
    """The L's outline [6, 2] in the block frame, counter-clockwise from the outer corner."""
    low, high = -ARM_WIDTH / 2, ARM_OFFSET + ARM_LENGTH / 2
    inner = ARM_WIDTH / 2
    return np.array(
        [[low, low], [high, low], [high, inner], [inner, inner], [inner, high], [low, high]]
    )


def block_parts() -> list[assets.Box]:
    """The block's two boxes: the arm along x and the arm along y."""
    return [
        assets.Box((ARM_LENGTH, ARM_WIDTH, BLOCK_HEIGHT), (ARM_OFFSET, 0.0, 0.0)),
        assets.Box((ARM_WIDTH, ARM_LENGTH, BLOCK_HEIGHT), (0.0, ARM_OFFSET, 0.0)),
    ]


def wall_centre_lines() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(start, end, outward normal) of the six walls' centre lines in the fixture frame: the
    block's outline pushed out by the clearance and half a wall."""
    outline = block_outline()
    directions = np.roll(outline, -1, axis=0) - outline
    normals = np.column_stack([directions[:, 1], -directions[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    push = CLEARANCE + WALL_THICKNESS / 2
    corners = outline + push * (np.roll(normals, 1, axis=0) + normals)
    return list(zip(corners, np.roll(corners, -1, axis=0), normals, strict=True))


def wall_box(
    start: np.ndarray,
    end: np.ndarray,
    normal: np.ndarray,
    thickness: float,
    shift: float = 0.0,
    color: assets.RGBA | None = None,
) -> assets.Box:
    """A wall along the axis-aligned centre line start-end (lengthened by a wall's thickness to
    close the corners), `thickness` across and moved `shift` along its outward `normal`."""
    along = np.abs(end - start) + WALL_THICKNESS
    size = np.where(np.abs(normal) > 0.5, thickness, along)
    centre = (start + end) / 2 + shift * normal
    return assets.Box((*map(float, size), WALL_HEIGHT), (*map(float, centre), 0.0), color=color)


def fixture_parts() -> tuple[list[assets.Box], list[assets.Box]]:
    """(visual, collision) boxes of the fixture: the pad and six walls around the L channel.

    Each wall collides as one 2 mm box and is drawn as two 1 mm halves, the channel's half dark.
    """
    pad = assets.Box(PAD_SIZE, (0.0, 0.0, -PAD_DEPTH), color=SLOT_COLOR)
    collision, visual = [pad], [pad]
    half = WALL_THICKNESS / 2
    for start, end, normal in wall_centre_lines():
        collision.append(wall_box(start, end, normal, WALL_THICKNESS))
        visual.append(wall_box(start, end, normal, half, -half / 2, SLOT_COLOR))
        visual.append(wall_box(start, end, normal, half, half / 2))
    return visual, collision


def seat_offset() -> Pose:
    """Pose, in the fixture frame, of a centred block standing on the pad."""
    height = -PAD_DEPTH + PAD_SIZE[2] / 2 + BLOCK_HEIGHT / 2
    return np.array([0.0, 0.0, height]), np.array([0.0, 0.0, 0.0, 1.0])


def footprint_radius(points: np.ndarray) -> float:
    """Radius about the origin of the disc that holds the x-y shadow of `points` [N, 2 or 3]
    in any orientation (the largest distance of a point from the origin)."""
    return float(np.linalg.norm(points, axis=1).max())


class BlockInsertion(Task):
    """One L block on the table and one fixed, tilted L fixture to insert it into."""

    name = "block-insertion"
    tolerance = MatchTolerance(position=0.02)  # the anchor's pos_eps 0.02 m, rot_eps 15 deg
    # stricter: 3-D position within the anchor's x-y limit, tilt and yaw within 15 deg
    strict_tolerance = Tolerance(position=0.02, tilt=math.radians(15), yaw=math.radians(15))

    def build(self, env: Scene, rng: np.random.Generator) -> None:
        outline = block_outline()
        block_xy = np.array([rng.uniform(*REGION[0]), rng.uniform(*REGION[1])])
        block = assets.write_urdf(
            "ell", block_parts(), BLOCK_COLOR, BLOCK_MASS, com=CENTER_OF_MASS, friction=FRICTION
        )
        pose = flat_pose(block_xy, BLOCK_HEIGHT / 2, self.sample_yaw(rng))
        self.object_id = assets.load(env.client, block, pose)

        visual, collision = fixture_parts()
        wall_corners = np.concatenate(
            [box_corners(np.divide(part.size, 2), part.position) for part in collision]
        )
        top_face = np.column_stack([outline, np.full(len(outline), BLOCK_HEIGHT / 2)])
        target = self.sample_target_pose(
            env,
            rng,
            REGION,
            FIXTURE_Z,
            top_face,
            taken=[(block_xy, footprint_radius(outline))],
            footprint=footprint_radius(wall_corners),
        )
        fixture = assets.write_urdf(
            "ell_fixture",
            visual,
            WALL_COLOR,
            FIXTURE_MASS,
            collision_parts=collision,
            com=CENTER_OF_MASS,
            friction=FRICTION,
        )
        self.target_ids = [assets.load(env.client, fixture, target, fixed=True)]
        self.target_poses = [target]  # the anchor's goal: the fixture's own pose
        self.strict_target_poses = [geometry.multiply_poses(target, seat_offset())]
