import math

import numpy as np
import pytest

from nerf_transporter import geometry as g
from tests.helpers.synthetic import table_height_in_view


@pytest.mark.parametrize("roll,pitch,yaw", [(0.0, 0.0, 0.0), (0.3, -0.4, 2.5), (-0.7, 0.6, -3.0)])
def test_euler_round_trip(roll, pitch, yaw):
    quat = g.euler_to_quat(roll, pitch, yaw)
    back = g.quat_to_euler(quat)
    assert np.allclose(back, (roll, pitch, g.wrap_angle(yaw)), atol=1e-9)


def test_euler_order_is_ry_rx_rz():
    roll, pitch, yaw = 0.2, -0.3, 1.1
    expected = g.rot_y(pitch) @ g.rot_x(roll) @ g.rot_z(yaw)
    assert np.allclose(g.euler_to_matrix(roll, pitch, yaw), expected)


def test_pixel_convention_matches_the_docs():
    assert np.allclose(g.pixel_to_world([0, 0], 0.0), [0.25, -0.5, 0.0])
    assert np.allclose(
        g.pixel_to_world([10, 20], 0.1), [0.25 + 20 * 0.003125, -0.5 + 10 * 0.003125, 0.1]
    )


def test_world_pixel_world_round_trip():
    rng = np.random.default_rng(0)
    points = rng.uniform(g.BOUNDS[:, 0], g.BOUNDS[:, 1], size=(100, 3))
    pixels = g.world_to_pixel(points)
    assert np.allclose(g.pixel_to_world(pixels, points[:, 2]), points)


def test_view_round_trip_and_flattening():
    rng = np.random.default_rng(1)
    rotation = g.tilt_matrix(0.4, -0.3)
    points = rng.uniform(g.BOUNDS[:, 0], g.BOUNDS[:, 1], size=(50, 3))
    pixels, height = g.world_to_view_pixel(points, rotation)
    assert np.allclose(g.view_pixel_to_world(pixels, height, rotation), points)
    # A plane tilted by the view's rotation looks flat in that view: its points share one height
    # and its normal maps to +z.
    offsets = np.concatenate([rng.uniform(-0.2, 0.2, size=(20, 2)), np.zeros((20, 1))], axis=1)
    on_plane = g.WORKSPACE_CENTER + offsets @ rotation.T
    assert np.allclose(g.world_to_view(on_plane, rotation)[:, 2], g.WORKSPACE_CENTER[2])
    normal_tip = g.WORKSPACE_CENTER + rotation @ np.array([0.0, 0.0, 1.0])
    assert np.allclose(g.world_to_view(normal_tip, rotation) - g.WORKSPACE_CENTER, [0, 0, 1])
    # The workspace centre is a fixed point of every view.
    assert np.allclose(g.world_to_view(g.WORKSPACE_CENTER, rotation), g.WORKSPACE_CENTER)


def test_table_seen_from_a_view_lies_on_the_table():
    rotation = g.tilt_matrix(0.3, -0.2)
    height = table_height_in_view(rotation, g.PIXEL_SIZE)
    pixels = np.stack(np.indices(height.shape), axis=-1)
    assert np.allclose(g.view_pixel_to_world(pixels, height, rotation)[..., 2], 0.0)


def test_view_grid_shapes_and_top_down():
    normal = g.view_grid("normal")
    challenging = g.view_grid("challenging")
    assert normal.shape == (49, 2) and challenging.shape == (121, 2)
    assert np.allclose(normal[g.top_down_view_index(normal)], 0)
    assert np.isclose(np.abs(normal).max(), math.pi / 6)
    assert np.isclose(np.abs(challenging).max(), math.pi / 4)
    assert g.nearest_view(0.01, -0.02, normal) == g.top_down_view_index(normal)


def test_pose_composition_and_inverse():
    a = (np.array([0.1, 0.2, 0.3]), g.euler_to_quat(0.1, 0.2, 0.3))
    b = (np.array([-0.4, 0.0, 0.05]), g.euler_to_quat(-0.3, 0.1, 2.0))
    ab = g.multiply_poses(a, b)
    back = g.multiply_poses(ab, g.invert_pose(b))
    assert np.allclose(back[0], a[0])
    assert g.rotation_angle(g.quat_to_matrix(back[1]), g.quat_to_matrix(a[1])) < 1e-9


@pytest.mark.parametrize("n", [8, 36])
def test_rotation_bin_round_trip(n):
    for k in range(n):
        assert g.angle_to_bin(g.bin_to_angle(k, n), n) == k
    assert g.angle_to_bin(-2 * math.pi / n, n) == n - 1


def test_image_shape_scales_with_pixel_size():
    assert g.image_shape() == g.IMAGE_SHAPE == (320, 160)
    assert g.image_shape(0.0125) == (80, 40)
    point = np.array([0.6, 0.1, 0.05])
    pixel = g.world_to_pixel(point, 0.0125)
    assert np.allclose(g.pixel_to_world(pixel, 0.05, 0.0125), point)


@pytest.mark.parametrize(
    "a_shape,b_shape",
    [
        ((3, 3), (3, 3)),
        ((4, 4), (4,)),
        ((3,), (3, 3)),
        ((3,), (3,)),
        ((50, 3), (3, 3)),
        ((7, 3, 3), (3, 3)),
        ((2, 5, 3), (3, 4)),
    ],
)
def test_matmul_is_numpys_product_in_every_shape(a_shape, b_shape):
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=a_shape), rng.normal(size=b_shape)
    product = g.matmul(a, b)
    assert np.shape(product) == np.shape(a @ b)
    assert np.allclose(product, a @ b, rtol=0, atol=1e-12)


def test_matmul_sums_in_index_order_and_refuses_misaligned_shapes():
    # (1e16 + 1) - 1e16 in index order: the 1 is lost, as the documented order says
    assert g.matmul([1e16, 1.0, -1e16], [1.0, 1.0, 1.0]) == 0.0
    with pytest.raises(ValueError, match=r"shapes \(3,\) and \(4,\) do not align"):
        g.matmul(np.ones(3), np.ones(4))


def test_rigid_inverse_norm_and_cos_sin():
    pose = (np.array([0.4, -0.2, 0.1]), g.euler_to_quat(0.3, -0.2, 1.0))
    matrix = g.pose_to_matrix(pose)
    assert np.allclose(g.matmul(matrix, g.invert_transform(matrix)), np.eye(4), atol=1e-12)
    assert g.norm([3.0, 4.0]) == 5.0
    angles = np.array([0.0, 0.5, -2.0])
    assert np.array_equal(g.cos_sin(angles), [[math.cos(a), math.sin(a)] for a in angles])
