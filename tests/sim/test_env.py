import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from nerf_transporter import geometry
from nerf_transporter.sim import cameras, make_env
from nerf_transporter.sim.robot import HOME_JOINTS, dh_frames


def test_unknown_task_or_setting_lists_valid_names():
    with pytest.raises(ValueError, match="block-insertion"):
        make_env("block-insertio")
    with pytest.raises(ValueError, match="normal, challenging, flat"):
        make_env("block-insertion", "hard")
    with pytest.raises(ValueError, match="state, rgbd, nerf"):
        make_env("block-insertion", rigs=("depth",))


def test_same_seed_gives_identical_poses_and_images():
    env = make_env(
        "block-insertion", rigs=("state", "nerf"), nerf_views=2, nerf_image_size=(48, 64)
    )
    first, _ = env.reset(seed=7)
    second, _ = env.reset(seed=7)
    other, _ = env.reset(seed=8)
    assert np.array_equal(first["state"], second["state"])
    assert np.array_equal(first["nerf"]["rgb"], second["nerf"]["rgb"])
    assert not np.array_equal(first["state"], other["state"])
    assert first["nerf"]["rgb"].shape == (2, 48, 64, 3)
    env.close()


def test_nerf_rig_can_be_other_cameras_without_changing_the_default():
    size = (48, 64)
    intrinsics = cameras.intrinsics_matrix(45.0, size)
    eyes = ((0.25 + 0.75 * np.cos(a), 0.75 * np.sin(a), 0.9) for a in (0.0, 2.0, 4.0))
    rig = [cameras.Camera(intrinsics, cameras.look_at(eye, (0.25, 0, 0)), size) for eye in eyes]
    env = make_env("block-insertion", rigs=("nerf",), nerf_cameras=rig)
    obs, _ = env.reset(seed=7)
    assert env.observation_space.contains(obs)
    assert obs["nerf"]["rgb"].shape == (3, 48, 64, 3)
    assert np.allclose(obs["nerf"]["cam_to_world"], [camera.cam_to_world for camera in rig])
    env.close()
    default = make_env("block-insertion", rigs=("nerf",), nerf_views=3, nerf_image_size=size)
    assert np.allclose(
        [camera.cam_to_world for camera in default.nerf_cameras],
        [camera.cam_to_world for camera in cameras.nerf_cameras(3, size)],
    )
    default.close()
    with pytest.raises(ValueError, match="nerf_views and nerf_image_size"):
        make_env("block-insertion", rigs=("nerf",), nerf_views=3, nerf_cameras=rig)


def test_gymnasium_env_checker_passes():
    env = make_env("block-insertion")
    check_env(env, skip_render_check=True)
    env.close()


def test_unreachable_action_ends_step_with_failure():
    env = make_env("block-insertion")
    env.reset(seed=3)
    far = (np.array([2.0, 0.0, 0.1]), np.array([0.0, 0.0, 0.0, 1.0]))
    _, reward, _, _, info = env.step({"pick": far, "place": far})
    assert reward == 0.0
    assert info["failure"].startswith("unreachable")
    env.close()


def test_inverse_kinematics_round_trip():
    env = make_env("block-insertion")
    env.reset(seed=0)
    robot = env.robot
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(20):
        q = HOME_JOINTS + rng.uniform(-0.6, 0.6, size=6)
        if min(frame[2, 3] for frame in dh_frames(q)[2:]) < 0.05:
            continue
        robot.set_joints(q)
        pose = robot.tip_pose()
        solution = robot.solve_ik(pose, HOME_JOINTS)
        robot.set_joints(solution)
        reached = robot.tip_pose()
        assert np.allclose(reached[0], pose[0], atol=1e-5)
        rotations = [geometry.quat_to_matrix(p[1]) for p in (reached, pose)]
        assert geometry.rotation_angle(*rotations) < 1e-4
        checked += 1
    assert checked >= 10
    env.close()


POSE = (np.array([0.5, 0.0, 0.05]), np.array([0.0, 0.0, 0.0, 1.0]))


@pytest.mark.parametrize(
    ("action", "problem"),
    [
        (None, "an action is {'pick': pose, 'place': pose}"),
        ({"pick": POSE}, "an action is {'pick': pose, 'place': pose}"),
        ({"pick": ((0.5, 0.0), (0, 0, 0, 1)), "place": POSE}, "got shapes (2,) and (4,)"),
        ({"pick": np.zeros(7), "place": POSE}, "action['pick'] must be (position [3], quaternion"),
        ({"pick": POSE, "place": ((0.5, 0.0, 0.05), (0, 0, 1))}, "got shapes (3,) and (3,)"),
        ({"pick": POSE, "place": None}, "action['place'] must be (position [3], quaternion [4])"),
    ],
    ids=["none", "no-place", "short-position", "flat-array", "short-quaternion", "none-pose"],
)
def test_a_malformed_action_or_a_step_after_close_is_a_named_error(action, problem):
    env = make_env("block-insertion")
    env.reset(seed=3)
    with pytest.raises(ValueError) as error:
        env.step(action)
    assert problem in str(error.value)
    env.close()
    with pytest.raises(RuntimeError, match=r"step\(\) after close\(\)"):
        env.step({"pick": POSE, "place": POSE})
