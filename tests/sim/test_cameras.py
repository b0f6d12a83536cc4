import numpy as np
import pybullet
import pytest
from pybullet_utils.bullet_client import BulletClient

from nerf_transporter import geometry
from nerf_transporter.sim import assets, cameras

BOX_SIZE = np.array([0.06, 0.1, 0.04])


@pytest.fixture()
def client():
    bullet = BulletClient(connection_mode=pybullet.DIRECT)
    table = assets.write_urdf("test_table", [assets.Box((1.6, 1.6, 0.02))], mass=0.0)
    assets.load(bullet, table, (np.array([0.5, 0.0, -0.01]), np.array([0, 0, 0, 1.0])), fixed=True)
    yield bullet
    bullet.disconnect()


def _add_box(client, position, rotation):
    path = assets.write_urdf(
        "test_box", [assets.Box(tuple(BOX_SIZE))], color=assets.COLORS["red"], mass=0.0
    )
    return assets.load(
        client, path, (np.asarray(position), geometry.matrix_to_quat(rotation)), fixed=True
    )


@pytest.mark.parametrize(
    "view,box_tilt,position",
    [
        ((0.0, 0.0), (0.0, 0.0), (0.4123, 0.2071, 0.02)),
        ((0.35, -0.45), (0.35, -0.45), (0.55, -0.12, 0.12)),
    ],
)
def test_orthographic_box_pixels_and_height(client, view, box_tilt, position):
    """A box tilted like the view looks flat in it: mask and top height where geometry predicts."""
    view_rotation = geometry.tilt_matrix(*view)
    rotation = geometry.tilt_matrix(*box_tilt) @ geometry.rot_z(0.4)
    body = _add_box(client, position, rotation)
    _, height, ids = cameras.render_orthographic(client, *view, segmentation=True)
    assert height.shape == geometry.IMAGE_SHAPE

    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    corners = np.asarray(position) + (signs * BOX_SIZE / 2) @ rotation.T
    predicted, corner_heights = geometry.world_to_view_pixel(corners, view_rotation)
    mask = np.argwhere(ids == body)
    assert np.all(np.abs(mask.min(axis=0) - np.ceil(predicted.min(axis=0))) <= 1)
    assert np.all(np.abs(mask.max(axis=0) - np.floor(predicted.max(axis=0))) <= 1)

    top_centre = np.asarray(position) + rotation @ np.array([0.0, 0.0, BOX_SIZE[2] / 2])
    pixel, expected_height = geometry.world_to_view_pixel(top_centre, view_rotation)
    row, col = np.round(pixel).astype(int)
    assert ids[row, col] == body
    assert abs(height[row, col] - expected_height) < 0.002
    assert abs(height[row, col] - corner_heights.max()) < 0.002


def test_orthographic_top_down_is_not_mirrored(client):
    """Rows grow with +y and columns with +x (docs/conventions.md, "Pixels"), unlike a camera image."""
    body = _add_box(client, (0.35, -0.3, 0.02), np.eye(3))
    _, _, ids = cameras.render_orthographic(client, 0.0, 0.0, segmentation=True)
    rows, cols = np.nonzero(ids == body)
    assert rows.mean() < geometry.IMAGE_SHAPE[0] / 2 and cols.mean() < geometry.IMAGE_SHAPE[1] / 2


def test_nerf_rig_intrinsics_and_poses_project_like_the_images(client):
    position = np.array([0.45, 0.1, 0.02])
    _add_box(client, position, np.eye(3))
    rig = cameras.nerf_cameras(4, image_size=(120, 160))
    capture = cameras.capture(client, rig)
    assert capture["rgb"].shape == (4, 120, 160, 3)
    assert np.allclose(capture["intrinsics"][:, 0, 0], 450 * 160 / 640)
    for rgb, intrinsics, cam_to_world in zip(
        capture["rgb"], capture["intrinsics"], capture["cam_to_world"], strict=True
    ):
        rotation = cam_to_world[:3, :3]
        assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-5)
        assert np.isclose(np.linalg.det(rotation), 1.0, atol=1e-5)
        top = position + np.array([0.0, 0.0, BOX_SIZE[2] / 2])
        local = np.linalg.inv(cam_to_world) @ np.append(top, 1.0)
        u, v = (intrinsics @ local[:3])[:2] / local[2]
        red = rgb[int(round(v)), int(round(u))]
        assert red[0] > 150 and red[1] < 100, red


def test_rgbd_depth_is_distance_along_the_optical_axis(client):
    rig = cameras.rgbd_cameras(image_size=(96, 128), focal=90.0)
    capture = cameras.capture(client, rig, depth=True)
    for depth, intrinsics, cam_to_world in zip(
        capture["depth"], capture["intrinsics"], capture["cam_to_world"], strict=True
    ):
        v, u = 60, 40
        ray = np.linalg.inv(intrinsics) @ np.array([u, v, 1.0])
        direction = cam_to_world[:3, :3] @ ray
        # the table top (z = 0) along this pixel's ray, at optical-axis depth t
        t = -cam_to_world[2, 3] / direction[2]
        assert abs(depth[v, u] - t) < 0.002
