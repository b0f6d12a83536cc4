"""Labels at their edges (the mutants of docs/mutation.md that test_labels.py let live): another
image size and rotation count than the defaults, the refusal's exact message, the upright pick."""

import math

import numpy as np
import pytest

from nerf_transporter import geometry as g
from nerf_transporter.data import labels as L

COARSE = 0.0125  # m per pixel: an 80 x 40 image
FLAT = np.array([0.0, 0.0, 0.0, 1.0])


def test_a_place_outside_a_coarse_image_is_refused_naming_it():
    """x = 0.80 m is column 44 of an 80 x 40 image: outside it (a check against the default
    image's 160 columns would let it through)."""
    assert g.image_shape(COARSE) == (80, 40)
    pick = (np.array([0.5, 0.0, 0.02]), FLAT)
    place = (np.array([0.801234, 0.1, 0.05]), FLAT)
    message = "place position [0.8012, 0.1, 0.05] maps to pixel (48, 44), outside the 80x40 image"
    with pytest.raises(ValueError) as refused:
        L.heightmap_labels({"pick": pick, "place": place}, pixel_size=COARSE)
    assert str(refused.value) == message


@pytest.mark.parametrize("n_rotations", [4, 8, 36])
def test_the_rotation_bin_counts_the_given_bins(n_rotations):
    """A place turned a quarter turn from the pick is bin n/4 of n (either labelling)."""
    pick = (np.array([0.5, 0.0, 0.02]), g.euler_to_quat(0.0, 0.0, 0.3))
    place = (np.array([0.6, 0.1, 0.05]), g.euler_to_quat(0.0, 0.0, 0.3 + math.pi / 2))
    action = {"pick": pick, "place": place}
    assert L.heightmap_labels(action, n_rotations=n_rotations).rotation_bin == n_rotations // 4
    grid = g.view_grid("normal")
    assert L.mira_labels(action, grid, n_rotations=n_rotations).rotation_bin == n_rotations // 4


def test_an_upright_pick_is_flat_at_the_same_float_position():
    pick = ([1, 0, 0], g.euler_to_quat(0.0, 0.0, 0.7))  # integers in, as a user may write them
    place = (np.array([0.6, 0.1, 0.05]), g.euler_to_quat(0.1, 0.0, 1.0))
    upright = L.upright_pick_action({"pick": pick, "place": place})
    assert np.array_equal(upright["pick"][1], FLAT)
    assert upright["pick"][0].dtype == np.float64 and upright["pick"][0].tolist() == [1.0, 0.0, 0.0]
    expected = g.quat_to_matrix(place[1]) @ g.rot_z(-0.7)
    assert np.allclose(g.quat_to_matrix(upright["place"][1]), expected)
    assert upright["place"][0] is place[0]


def test_a_pose_in_a_view_comes_back_to_the_world():
    """`pose_from_view` undoes `pose_in_view`; in the view of its own tilt a pose is flat."""
    view = g.tilt_matrix(0.3, -0.2)
    pose = (np.array([0.6, -0.1, 0.07]), g.matrix_to_quat(view @ g.rot_z(0.8)))
    in_view = L.pose_in_view(pose, view)
    assert np.allclose(g.quat_to_euler(in_view[1]), (0.0, 0.0, 0.8))
    back = L.pose_from_view(in_view, view)
    assert np.allclose(back[0], pose[0])
    assert np.allclose(g.quat_to_matrix(back[1]), g.quat_to_matrix(pose[1]))
