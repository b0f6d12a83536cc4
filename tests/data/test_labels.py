import math

import numpy as np
import pytest

from nerf_transporter import geometry as g
from nerf_transporter.data import labels as L

HALF_BIN = math.pi / g.N_ROTATIONS
HALF_STEP = (math.pi / 3) / 6 / 2  # normal grid: 7 views over [-pi/6, pi/6]


def _random_action(rng: np.random.Generator) -> L.Action:
    pick = (
        np.array([rng.uniform(0.3, 0.7), rng.uniform(-0.4, 0.4), rng.uniform(0.0, 0.05)]),
        g.euler_to_quat(0.0, 0.0, rng.uniform(-math.pi, math.pi)),
    )
    place = (
        np.array([rng.uniform(0.3, 0.7), rng.uniform(-0.4, 0.4), rng.uniform(0.02, 0.15)]),
        g.euler_to_quat(*rng.uniform(-math.pi / 6, math.pi / 6, 2), rng.uniform(-math.pi, math.pi)),
    )
    return {"pick": pick, "place": place}


def _check_round_trip(action, grid, pixel_size):
    labels = L.mira_labels(action, grid, pixel_size)
    view = L.to_view_frames(action, grid)
    rebuilt = L.action_from_labels(
        labels.pick_pixel,
        view.pick[0][2],
        labels.place_pixel,
        view.place[0][2],
        labels.rotation_bin,
        place_view=tuple(grid[labels.place_view]),
        pixel_size=pixel_size,
    )
    target = L.upright_pick_action(action)
    # positions within one pixel (rounding error <= half a pixel per image axis)
    for name in ("pick", "place"):
        assert (
            np.linalg.norm(rebuilt[name][0] - target[name][0]) <= pixel_size * math.sqrt(0.5) + 1e-9
        )
    # place tilt within half a grid step, yaw (in the place view) within half a bin
    roll, pitch, _ = g.quat_to_euler(target["place"][1])
    view_roll, view_pitch = grid[labels.place_view]
    assert abs(roll - view_roll) <= HALF_STEP + 1e-9 and abs(pitch - view_pitch) <= HALF_STEP + 1e-9
    rebuilt_in_view = L.pose_in_view(rebuilt["place"], g.tilt_matrix(view_roll, view_pitch))
    target_in_view = L.pose_in_view(target["place"], g.tilt_matrix(view_roll, view_pitch))
    yaw_error = g.wrap_angle(
        g.quat_to_euler(rebuilt_in_view[1])[2] - g.quat_to_euler(target_in_view[1])[2]
    )
    assert abs(yaw_error) <= HALF_BIN + 1e-9
    angle = g.rotation_angle(
        g.quat_to_matrix(rebuilt["place"][1]), g.quat_to_matrix(target["place"][1])
    )
    assert angle <= HALF_BIN + math.sqrt(2) * HALF_STEP + 1e-9
    assert np.allclose(rebuilt["pick"][1], [0, 0, 0, 1])
    # the rebuilt action has the same discrete labels
    again = L.mira_labels(rebuilt, grid, pixel_size)
    assert (again.pick_pixel, again.place_view, again.place_pixel, again.rotation_bin) == (
        labels.pick_pixel,
        labels.place_view,
        labels.place_pixel,
        labels.rotation_bin,
    )


@pytest.mark.parametrize("pixel_size", [g.PIXEL_SIZE, 0.0125])
def test_mira_round_trip(pixel_size):
    rng = np.random.default_rng(0)
    grid = g.view_grid("normal")
    for _ in range(100):
        _check_round_trip(_random_action(rng), grid, pixel_size)


def test_heightmap_round_trip_keeps_tilt_and_z():
    rng = np.random.default_rng(1)
    for _ in range(100):
        action = _random_action(rng)
        labels = L.heightmap_labels(action)
        roll, pitch, _ = g.quat_to_euler(action["place"][1])
        assert labels.place_view == 0
        assert math.isclose(labels.place_z, action["place"][0][2], abs_tol=1e-12)
        assert math.isclose(labels.place_roll, roll) and math.isclose(labels.place_pitch, pitch)
        rebuilt = L.action_from_labels(
            labels.pick_pixel,
            action["pick"][0][2],
            labels.place_pixel,
            labels.place_z,
            labels.rotation_bin,
            place_tilt=(labels.place_roll, labels.place_pitch),
        )
        target = L.upright_pick_action(action)
        assert np.linalg.norm(rebuilt["place"][0] - target["place"][0]) <= g.PIXEL_SIZE * 0.71
        angle = g.rotation_angle(
            g.quat_to_matrix(rebuilt["place"][1]), g.quat_to_matrix(target["place"][1])
        )
        assert angle <= HALF_BIN + 1e-9


def test_rotation_bin_is_relative_yaw():
    pick = (np.array([0.5, 0.0, 0.02]), g.euler_to_quat(0.0, 0.0, 0.5))
    place = (np.array([0.6, 0.1, 0.05]), g.euler_to_quat(0.0, 0.0, 0.5 + 2 * math.pi * 7 / 36))
    labels = L.heightmap_labels({"pick": pick, "place": place})
    assert labels.rotation_bin == 7
    assert labels.pick_pixel == (160, 80) and labels.place_pixel == (192, 112)


def test_label_outside_image_is_an_error():
    pick = (np.array([0.9, 0.0, 0.02]), np.array([0.0, 0.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="pick position .* outside"):
        L.heightmap_labels({"pick": pick, "place": pick})
