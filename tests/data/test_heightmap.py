import numpy as np
import pytest

from nerf_transporter import geometry as g
from nerf_transporter.data.heightmap import back_project, heightmap_from_rgbd


def test_back_projection_of_a_camera_looking_down():
    camera = np.eye(4)
    camera[:3, :3] = np.diag([1.0, -1.0, -1.0])  # OpenCV: x right, y down, z forward (world -z)
    camera[:3, 3] = [0.5, 0.0, 1.0]
    intrinsics = np.array([[100.0, 0.0, 2.0], [0.0, 100.0, 1.0], [0.0, 0.0, 1.0]])
    depth = np.full((3, 5), 0.8)
    points = back_project(depth, intrinsics, camera)
    assert np.allclose(points[1, 2], [0.5, 0.0, 0.2])  # principal point
    assert np.allclose(points[1, 3] - points[1, 2], [0.008, 0.0, 0.0])  # +u is +x here
    assert np.allclose(points[2, 2] - points[1, 2], [0.0, -0.008, 0.0])  # +v is -y here


@pytest.mark.parametrize("seed", [0, 3])
def test_fused_heightmap_matches_ground_truth_top_down_render(seed):
    pytest.importorskip("pybullet")
    from nerf_transporter.sim import make_env

    env = make_env("block-insertion", "normal", rigs=("rgbd",))
    try:
        obs, _ = env.reset(seed=seed)
        colour, height = heightmap_from_rgbd(obs["rgbd"])
        true_colour, true_height = env.render_orthographic(0.0, 0.0)
    finally:
        env.close()
    assert colour.shape == true_colour.shape and height.shape == true_height.shape == g.IMAGE_SHAPE
    seen = colour.any(axis=-1)  # pixels no camera sees stay black
    assert seen.mean() > 0.95  # the three cameras cover the workspace
    error = np.abs(height - true_height)[seen]
    assert error.mean() < 0.003 and np.median(error) < 0.002  # metres
    objects = true_height > 0.01
    assert objects.any() and np.median(np.abs(height - true_height)[objects & seen]) < 0.005
    assert np.abs(colour[seen].astype(int) - true_colour[seen].astype(int)).mean() < 10
