"""place-red-in-green: put the red cube into any of 1-3 tilted green bowls, among ten distractors
(the anchor's `PlaceRedInGreenSixDof`; Challenging its `PlaceRedInGreenSixDofOOD`).

The scene is built in the anchor's order: the green bowls (fixed and tilted, origin 3 cm above the
table at every tilt), the red cube (flat), then ten distractors (each a block or a bowl with equal
chance, movable and flat). Every origin is drawn uniformly from the free workspace, half the
diagonal of the anchor's size of the object away from what is already there and from the
workspace's edge (the anchor erodes the free pixels by that diagonal).

The bowl's body origin lies 2.15 cm off its axis (the anchor's mesh is off-centre), and success is
the anchor's: the cube's origin within 5 cm in x-y of any green bowl's origin, at any orientation.
The strict check asks for the cube seated in a bowl: its centre within 2.5 cm in 3-D of a cube
resting on the middle of that bowl's floor; orientation free (any face of the cube may lie down).

The oracle seats the cube there, in the nearest green bowl (the anchor's choice of bowl). The
anchor's oracle aims at the bowl's origin instead: a cube centred there overhangs the cavity's
wall, lands on the rim and stays there or wedges against it, never seated (measured here: the
anchor's check then still passes on Normal tilts, but on under half of the Challenging ones).
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
    placeable,
    sample_free_xy,
    sampling_radius,
    sampling_region,
)

GREEN_BOWLS = (1, 3)  # the anchor draws 1 to 3 green bowls, uniformly
DISTRACTORS = 10  # the anchor's
BOWL_Z = 0.03  # m, a green bowl's origin height at every tilt (the anchor's size z 0 / 2 + 0.03)
CUBE_MASS = 0.01  # kg (the anchor's stacking/block.urdf)
CUBE_FRICTION = 1.0  # lateral (the anchor's)
CUBE_CENTER_OF_MASS = (0.0, 0.0, 0.0)  # the anchor's URDF puts it at the link origin

# the anchor's sizes for its free-space sampling (`get_random_pose`): an origin stays half their
# diagonal away from every occupied pixel and from the edge of the workspace
BOWL_SAMPLING_SIZE = (0.12, 0.12)
CUBE_SAMPLING_SIZE = (shapes.CUBE_SIZE, shapes.CUBE_SIZE)
BOWL_CLEARANCE = sampling_radius(BOWL_SAMPLING_SIZE)
CUBE_CLEARANCE = sampling_radius(CUBE_SAMPLING_SIZE)
BOWL_REGION = sampling_region(BOWL_SAMPLING_SIZE)
CUBE_REGION = sampling_region(CUBE_SAMPLING_SIZE)

# the anchor's palette in its order, less green for the distractor bowls and less red for the
# distractor blocks; the k-th distractor takes the k-th colour of its kind (the anchor's rule)
PALETTE = (
    "blue",
    "red",
    "green",
    "orange",
    "yellow",
    "purple",
    "pink",
    "cyan",
    "brown",
    "white",
    "gray",
)
DISTRACTOR_BOWL_COLORS = tuple(color for color in PALETTE if color != "green")
DISTRACTOR_BLOCK_COLORS = tuple(color for color in PALETTE if color != "red")


def cube_urdf(color: str) -> str:
    """The anchor's 4 cm block in `color`."""
    box = assets.Box((shapes.CUBE_SIZE,) * 3)
    path = assets.write_urdf(
        "cube",
        [box],
        color=assets.COLORS[color],
        mass=CUBE_MASS,
        com=CUBE_CENTER_OF_MASS,
        friction=CUBE_FRICTION,
    )
    return str(path)


def silhouette(pose: Pose, points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre, radius) of an x-y disc holding `points` [N, 3] (body frame) of a body at `pose`."""
    world = geometry.matmul(points, geometry.quat_to_matrix(pose[1]).T) + np.asarray(pose[0])
    low, high = world[:, :2].min(axis=0), world[:, :2].max(axis=0)
    centre = (low + high) / 2
    return centre, float(np.linalg.norm(world[:, :2] - centre, axis=1).max())


def pick_points() -> np.ndarray:
    """Points [9, 3], in the cube's frame, where the oracle may hold it: its top face's centre and
    a ring around the part of the face inside the suction margin, whatever the cube's yaw."""
    reach = (shapes.CUBE_SIZE / 2 - SUCTION_MARGIN) * math.sqrt(2)
    angles = 2 * math.pi * np.arange(8) / 8
    ring = reach * np.column_stack([geometry.cos_sin(angles), np.zeros(8)])
    return np.array([0.0, 0.0, shapes.CUBE_SIZE / 2]) + np.vstack([np.zeros(3), ring])


class PlaceRedInGreen(Task):
    name = "place-red-in-green"
    tolerance = MatchTolerance(position=0.05, yaw=None)  # the anchor's pos_eps, symmetry 0
    # stricter: seated in the bowl in 3-D (the seat 2 cm out along the bowl's axis from its floor)
    strict_tolerance = Tolerance(position=0.025)
    max_targets = GREEN_BOWLS[1]

    def build(self, env: Scene, rng: np.random.Generator) -> None:
        bowl_points = np.concatenate(shapes.bowl_pieces())
        seat = (shapes.bowl_seat(), np.array([0.0, 0.0, 0.0, 1.0]))
        green = shapes.bowl_urdf(assets.COLORS["green"])
        taken: list[tuple[np.ndarray, float]] = []  # x-y discs of the bodies loaded so far
        for _ in range(int(rng.integers(GREEN_BOWLS[0], GREEN_BOWLS[1] + 1))):
            pose = self.sample_target_pose(
                env,
                rng,
                BOWL_REGION,
                BOWL_Z,
                shapes.bowl_seat() + pick_points(),  # the cube seated, in the bowl's frame
                taken=taken,
                footprint=BOWL_CLEARANCE,
            )
            taken.append(silhouette(pose, bowl_points))
            self.target_ids.append(assets.load(env.client, green, pose, fixed=True))
            self.target_poses.append(pose)
            self.strict_target_poses.append(geometry.multiply_poses(pose, seat))

        pose = self._pickable_cube_pose(env, rng, taken)
        taken.append((pose[0][:2], shapes.CUBE_SIZE / math.sqrt(2)))
        self.object_id = assets.load(env.client, cube_urdf("red"), pose)
        self._add_distractors(env, rng, taken, bowl_points)

    def _pickable_cube_pose(
        self, env: Scene, rng: np.random.Generator, taken: list, attempts: int = 100
    ) -> Pose:
        """A flat cube pose in free space whose top face the arm reaches from above."""
        half = shapes.CUBE_SIZE / 2
        for _ in range(attempts):
            xy = sample_free_xy(rng, CUBE_CLEARANCE, taken, CUBE_REGION)
            pose = flat_pose(xy, half, self.sample_yaw(rng))
            if placeable(env, pose, pick_points()):
                return pose
        raise RuntimeError(f"task {self.name!r}: no reachable spot for the cube")

    def _add_distractors(
        self, env: Scene, rng: np.random.Generator, taken: list, bowl_points: np.ndarray
    ) -> None:
        """Ten movable, flat bowls or blocks; a bowl that finds no room is drawn again (a block or
        a bowl), as in the anchor."""
        while len(self.distractor_ids) < DISTRACTORS:
            index = len(self.distractor_ids)
            is_block = rng.random() > 0.5  # the anchor's draw
            clearance, region = (
                (CUBE_CLEARANCE, CUBE_REGION) if is_block else (BOWL_CLEARANCE, BOWL_REGION)
            )
            try:
                xy = sample_free_xy(rng, clearance, taken, region)
            except RuntimeError:
                if is_block:
                    raise
                continue
            yaw = self.sample_yaw(rng)
            if is_block:
                pose = flat_pose(xy, shapes.CUBE_SIZE / 2, yaw)
                color = DISTRACTOR_BLOCK_COLORS[index % len(DISTRACTOR_BLOCK_COLORS)]
                body = assets.load(env.client, cube_urdf(color), pose)
                taken.append((xy, shapes.CUBE_SIZE / math.sqrt(2)))
            else:
                pose = flat_pose(xy, 0.0, yaw)
                color = DISTRACTOR_BOWL_COLORS[index % len(DISTRACTOR_BOWL_COLORS)]
                body = assets.load(env.client, shapes.bowl_urdf(assets.COLORS[color]), pose)
                taken.append(silhouette(pose, bowl_points))
            self.distractor_ids.append(body)

    def oracle_target(self, env: Scene, object_pose: Pose) -> Pose:
        """The cube seated in the nearest green bowl (the anchor's choice of bowl), keeping its yaw
        and taking the bowl's tilt (the cube is square and the cavity round)."""
        distances = [geometry.norm(pose[0] - object_pose[0]) for pose in self.target_poses]
        nearest = int(np.argmin(distances))
        roll, pitch, _ = geometry.quat_to_euler(self.target_poses[nearest][1])
        rotation = geometry.matmul(
            geometry.tilt_matrix(roll, pitch), geometry.quat_to_matrix(object_pose[1])
        )
        return self.strict_target_poses[nearest][0], geometry.matrix_to_quat(rotation)
