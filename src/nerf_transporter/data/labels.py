"""Oracle action <-> training labels, and predicted labels -> action (docs/conventions.md,
"Labels and actions").

Labels are computed from the action expressed in the frames of two views: the pick view (always the
top-down view) and the place view (the grid view nearest to the place tilt for `mira`; the top-down
view for the heightmap methods). In a view frame a pose is flat up to a residual tilt, and

- the pixel is the rounded (row, col) of its position,
- the rotation bin is (place yaw - pick yaw), both yaws read in their own view frame,
- `place_z`, `place_roll`, `place_pitch` are the place pose's height and residual tilt in its view
  (for the top-down view these are the world z, roll and pitch).

Image augmentation (`augment.py`) moves poses inside their view frames, so labels after augmentation
come from the same functions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nerf_transporter import geometry as g

Action = dict[str, g.Pose]


@dataclass(frozen=True)
class ViewAction:
    """An action with its pick pose in the top-down frame and its place pose in view `place_view`."""

    place_view: int
    pick: g.Pose
    place: g.Pose


@dataclass(frozen=True)
class Labels:
    pick_pixel: tuple[int, int]
    place_view: int
    place_pixel: tuple[int, int]
    rotation_bin: int
    place_z: float
    place_roll: float
    place_pitch: float


def pose_in_view(pose: g.Pose, view_rotation: np.ndarray) -> g.Pose:
    """World pose -> the same pose in the frame of view v (P' = R_v^T (P - c) + c, R' = R_v^T R)."""
    position, quat = pose
    rotation = np.asarray(view_rotation).T @ g.quat_to_matrix(quat)
    return g.world_to_view(position, view_rotation), g.matrix_to_quat(rotation)


def pose_from_view(pose: g.Pose, view_rotation: np.ndarray) -> g.Pose:
    """Inverse of `pose_in_view`."""
    position, quat = pose
    rotation = np.asarray(view_rotation) @ g.quat_to_matrix(quat)
    return g.view_to_world(position, view_rotation), g.matrix_to_quat(rotation)


def to_view_frames(action: Action, grid: np.ndarray) -> ViewAction:
    """Express an action in the top-down view (pick) and the grid view nearest its place tilt."""
    roll, pitch, _ = g.quat_to_euler(action["place"][1])
    place_view = g.nearest_view(roll, pitch, grid)
    rotations = g.view_rotations(grid)
    top_down = rotations[g.top_down_view_index(grid)]
    return ViewAction(
        place_view=place_view,
        pick=pose_in_view(action["pick"], top_down),
        place=pose_in_view(action["place"], rotations[place_view]),
    )


def continuous_pixel(position: np.ndarray, pixel_size: float) -> np.ndarray:
    """(row, col) of a view-frame position, not rounded."""
    return g.world_to_pixel(position, pixel_size)


def labels_from_view_action(
    view_action: ViewAction,
    pixel_size: float = g.PIXEL_SIZE,
    n_rotations: int = g.N_ROTATIONS,
) -> Labels:
    """Labels of an action given in view frames; ValueError if a pixel falls outside the image."""
    shape = g.image_shape(pixel_size)
    pixels = []
    for name, pose in (("pick", view_action.pick), ("place", view_action.place)):
        pixel = tuple(int(v) for v in np.round(continuous_pixel(pose[0], pixel_size)))
        if not g.pixel_inside_image(pixel, shape):
            raise ValueError(
                f"{name} position {np.round(pose[0], 4).tolist()} maps to pixel {pixel}, outside "
                f"the {shape[0]}x{shape[1]} image"
            )
        pixels.append(pixel)
    _, _, pick_yaw = g.quat_to_euler(view_action.pick[1])
    roll, pitch, place_yaw = g.quat_to_euler(view_action.place[1])
    return Labels(
        pick_pixel=pixels[0],
        place_view=view_action.place_view,
        place_pixel=pixels[1],
        rotation_bin=g.angle_to_bin(place_yaw - pick_yaw, n_rotations),
        place_z=float(view_action.place[0][2]),
        place_roll=float(roll),
        place_pitch=float(pitch),
    )


def mira_labels(
    action: Action,
    grid: np.ndarray,
    pixel_size: float = g.PIXEL_SIZE,
    n_rotations: int = g.N_ROTATIONS,
) -> Labels:
    """Labels of the imagery method: place view nearest to the place tilt, pixel and yaw in it."""
    return labels_from_view_action(to_view_frames(action, grid), pixel_size, n_rotations)


def heightmap_labels(
    action: Action, pixel_size: float = g.PIXEL_SIZE, n_rotations: int = g.N_ROTATIONS
) -> Labels:
    """Labels of the top-down methods: pixels, rotation bin, world place z, roll and pitch."""
    return mira_labels(action, np.zeros((1, 2)), pixel_size, n_rotations)


def action_from_labels(
    pick_pixel: tuple[int, int] | np.ndarray,
    pick_height: float,
    place_pixel: tuple[int, int] | np.ndarray,
    place_height: float,
    rotation_bin: int,
    *,
    place_view: tuple[float, float] = (0.0, 0.0),
    place_tilt: tuple[float, float] = (0.0, 0.0),
    pixel_size: float = g.PIXEL_SIZE,
    n_rotations: int = g.N_ROTATIONS,
) -> Action:
    """Predicted labels -> action: upright pick at the top-down pixel and height; place at the pixel
    and height of view `place_view` = (roll, pitch), oriented R_v . R_tilt(place_tilt) . Rz(theta).

    `mira` passes its place view and no tilt; the heightmap methods pass the top-down view, the
    predicted (or zero) tilt and their z as `place_height`.
    """
    view_rotation = g.tilt_matrix(*place_view)
    pick_position = g.pixel_to_world(np.asarray(pick_pixel), pick_height, pixel_size)
    place_in_view = g.pixel_to_world(np.asarray(place_pixel), place_height, pixel_size)
    theta = g.bin_to_angle(rotation_bin, n_rotations)
    place_rotation = view_rotation @ g.euler_to_matrix(place_tilt[0], place_tilt[1], theta)
    return {
        "pick": (pick_position, np.array([0.0, 0.0, 0.0, 1.0])),
        "place": (g.view_to_world(place_in_view, view_rotation), g.matrix_to_quat(place_rotation)),
    }


def upright_pick_action(action: Action) -> Action:
    """The same action with an upright pick: the place pose turns by the pick's yaw as well.

    With suction the pick yaw is free; fixing it to zero rotates the grasped object's frame, so the
    place orientation becomes place . Rz(-pick yaw). This is what `action_from_labels` reproduces.
    """
    _, _, pick_yaw = g.quat_to_euler(action["pick"][1])
    pick = (np.asarray(action["pick"][0], dtype=float), np.array([0.0, 0.0, 0.0, 1.0]))
    place_rotation = g.quat_to_matrix(action["place"][1]) @ g.rot_z(-pick_yaw)
    return {"pick": pick, "place": (action["place"][0], g.matrix_to_quat(place_rotation))}
