import numpy as np
import pytest
import torch

from nerf_transporter import geometry
from nerf_transporter.imagery.rays import (
    ORTHO_START_HEIGHT,
    depth_to_height,
    make_rays,
    orthographic_rays,
    perspective_rays,
)
from nerf_transporter.imagery.synthetic import ring_cameras


def test_top_down_rays_land_exactly_on_the_convention_pixel_grid():
    rays = orthographic_rays(0.0, 0.0)
    rows, cols = geometry.image_shape()
    assert len(rays) == rows * cols == 320 * 160
    grid = np.stack(np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij"), -1).reshape(-1, 2)
    expected = geometry.pixel_to_world(grid, ORTHO_START_HEIGHT)
    assert np.allclose(rays.origins.numpy(), expected, atol=1e-6)
    assert np.allclose(rays.directions.numpy(), [0.0, 0.0, -1.0])
    # (row 10, col 20) is x = 0.25 + 20 s, y = -0.5 + 10 s, as docs/conventions.md ("Pixels") says
    assert np.allclose(rays.origins[10 * cols + 20, :2].numpy(), [0.3125, -0.46875], atol=1e-6)
    # every ray stays on its pixel all the way down, and ends on the floor at height 0
    assert np.allclose(depth_to_height(rays.floor).numpy(), 0.0, atol=1e-5)


@pytest.mark.parametrize("roll,pitch", [(0.3, -0.2), (-np.pi / 6, np.pi / 6), (np.pi / 4, 0.1)])
def test_tilted_view_maps_a_world_point_to_the_predicted_pixel_and_height(roll, pitch):
    rotation = geometry.tilt_matrix(roll, pitch)
    point = np.array([0.47, 0.13, 0.06])
    (row, col), height = geometry.world_to_view_pixel(point, rotation)
    pixel = np.round([row, col]).astype(int)
    # move the point onto that pixel's centre, keeping its height in the view
    point = geometry.view_pixel_to_world(pixel.astype(float), height, rotation)
    rays = orthographic_rays(roll, pitch)
    index = pixel[0] * geometry.image_shape()[1] + pixel[1]
    distance = ORTHO_START_HEIGHT - height
    on_ray = rays.origins[index].double() + distance * rays.directions[index].double()
    assert np.allclose(on_ray.numpy(), point, atol=1e-5)
    assert float(depth_to_height(torch.tensor(distance))) == pytest.approx(height)


def test_pixel_size_is_configurable():
    rays = orthographic_rays(0.0, 0.0, pixel_size=0.0125)
    assert len(rays) == 80 * 40
    assert np.allclose(rays.origins[41, :2].numpy(), [0.25 + 0.0125, -0.5 + 0.0125], atol=1e-6)


def test_perspective_ray_passes_through_the_projected_point():
    intrinsics, poses = ring_cameras(4, (48, 64), 40.0)
    point = np.array([0.52, -0.07, 0.03])
    camera = 2
    in_camera = np.linalg.inv(poses[camera]) @ np.append(point, 1.0)
    u, v, w = intrinsics[camera] @ in_camera[:3]
    rays = perspective_rays(
        torch.as_tensor(intrinsics),
        torch.as_tensor(poses),
        torch.tensor([camera]),
        torch.tensor([v / w]),
        torch.tensor([u / w]),
    )
    to_point = point - rays.origins[0].numpy()
    along = to_point @ rays.directions[0].numpy()
    assert np.linalg.norm(to_point - along * rays.directions[0].numpy()) < 1e-5


def test_box_interval_and_floor_exit():
    origins = torch.tensor([[0.5, 0.0, 1.0], [0.5, 0.0, 0.1], [0.0, 0.0, 1.0]])
    directions = torch.tensor([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    rays = make_rays(origins, directions)
    assert rays.near[0] == pytest.approx(0.72) and rays.far[0] == pytest.approx(1.0)
    # straight down leaves through the floor; sideways leaves through the wall x = 0.75; outside misses
    assert rays.exits_through_floor.tolist() == [True, False, False]
    assert rays.far[1] == pytest.approx(0.25)
    assert rays.floor[2] == pytest.approx(1.0)
