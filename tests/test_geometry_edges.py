"""geometry at the survivors of a mutation run (docs/mutation.md): the angle between rotations,
angle wrapping, the view grid's order, the nearest view, a pixel inside the image and the view
rotations, each against values worked out by hand."""

import math

import numpy as np
import pytest

from nerf_transporter import geometry as g


@pytest.mark.parametrize("angle", [0.3, 1.2, math.pi - 1e-6])
def test_the_angle_between_rotations_is_the_turn_between_them(angle):
    assert g.rotation_angle(np.eye(3), g.rot_z(angle)) == pytest.approx(angle, abs=1e-6)
    assert g.rotation_angle(g.tilt_matrix(angle / 2, 0.0), g.tilt_matrix(angle / 2, 0.0)) == (
        pytest.approx(0.0, abs=1e-6)
    )


def test_a_turn_about_z_leaves_z_alone():
    assert np.allclose(g.rot_z(0.7) @ np.array([0.0, 0.0, 1.0]), [0.0, 0.0, 1.0])


@pytest.mark.parametrize(
    ("angle", "wrapped"), [(4.0, 4.0 - 2 * math.pi), (-4.0, 2 * math.pi - 4.0)]
)
def test_an_angle_wraps_into_minus_pi_to_pi(angle, wrapped):
    assert g.wrap_angle(angle) == pytest.approx(wrapped)


def test_the_view_grid_is_roll_major_and_normal_by_default():
    """View k = roll index k // n, pitch index k % n (the view indices the labels and records use)."""
    grid = g.view_grid()
    assert np.array_equal(grid, g.view_grid("normal")) and grid.shape == (49, 2)
    angles = np.linspace(-math.pi / 6, math.pi / 6, 7)
    assert np.allclose(grid[1], (angles[0], angles[1]))
    assert np.allclose(grid[7], (angles[1], angles[0]))


def test_the_nearest_view_tells_roll_from_pitch_and_their_signs():
    grid = g.view_grid()
    for roll, pitch in ((0.5, -0.17), (-0.35, 0.52), (0.17, 0.35)):
        view = g.nearest_view(roll, pitch, grid)
        assert np.allclose(grid[view], (roll, pitch), atol=math.pi / 36)


def test_a_pixel_is_inside_the_image_from_zero_to_below_its_shape():
    rows, cols = g.IMAGE_SHAPE
    for pixel in ((0, 0), (rows - 1, cols - 1), (0, cols - 1), (rows - 1, 0)):
        assert g.pixel_inside_image(pixel)
    for pixel in ((-1, 0), (0, -1), (rows, 0), (0, cols), (rows, cols), (cols, rows - 1)):
        assert not g.pixel_inside_image(pixel), pixel


def test_the_view_rotations_are_the_tilts_of_the_grid():
    grid = np.array([[0.3, -0.1], [-0.2, 0.4]])
    rotations = g.view_rotations(grid)
    assert rotations.shape == (2, 3, 3)
    for rotation, (roll, pitch) in zip(rotations, grid, strict=True):
        assert np.allclose(rotation, g.tilt_matrix(roll, pitch))
