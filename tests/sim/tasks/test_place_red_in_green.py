import math

import numpy as np
import pytest

from nerf_transporter import geometry
from nerf_transporter.sim import assets, make_env, shapes
from nerf_transporter.sim.tasks import place_red_in_green as prg
from tests.helpers.tasks import assert_oracle_reachable, in_frame, teleport

TASK = "place-red-in-green"
ENV_SEED = 12  # the scene of the `env` fixture (conftest.py): two green bowls
ONE_BOWL_SEED = 11


def _rgb(env, body):
    return np.array(env.client.getVisualShapeData(body)[0][7][:3])


def _is_color(env, body, name):
    return np.allclose(_rgb(env, body), assets.COLORS[name][:3], atol=1e-3)


def _is_bowl(env, body):
    return len(env.client.getCollisionShapeData(body, -1)) > 1  # a compound; a block is one box


def _seated(env, target_index=0):
    """Drop the cube onto the middle of a bowl's floor and let it settle."""
    seat = env.task.strict_target_poses[target_index]
    teleport(env, in_frame(seat, (0.0, 0.0, 0.002)))
    env.settle()


def test_scene_has_one_to_three_fixed_tilted_green_bowls_at_the_anchors_height(env):
    counts = set()
    for seed in (10, 11, 12):  # three, one and two bowls
        env.reset(seed=seed)
        task = env.task
        counts.add(len(task.target_ids))
        assert len(task.target_ids) == len(task.target_poses) == len(task.strict_target_poses)
        for body, target in zip(task.target_ids, task.target_poses, strict=True):
            assert not env.is_dynamic(body) and _is_color(env, body, "green")
            position, quat = assets.get_pose(env.client, body)
            assert position == pytest.approx(target[0], abs=1e-6)
            assert position[2] == pytest.approx(0.03)  # the anchor's origin z at every tilt
            roll, pitch, _ = geometry.quat_to_euler(quat)
            assert max(abs(roll), abs(pitch)) <= math.pi / 6 + 1e-9
    assert counts == {1, 2, 3} and prg.PlaceRedInGreen.max_targets == 3


def test_the_red_cube_is_the_anchors_block(env):
    env.reset(seed=ENV_SEED)
    cube = env.task.object_id
    assert _is_color(env, cube, "red") and env.is_dynamic(cube)
    mass, friction = env.client.getDynamicsInfo(cube, -1)[0:2]
    assert mass == pytest.approx(0.01) and friction == pytest.approx(1.0)
    low, high = env.client.getAABB(cube)
    assert sorted(np.subtract(high, low))[0] == pytest.approx(0.04, abs=2e-3)
    position, quat = assets.get_pose(env.client, cube)
    assert position[2] == pytest.approx(0.02, abs=1e-3)
    assert geometry.quat_to_euler(quat)[:2] == pytest.approx((0.0, 0.0), abs=1e-3)


def test_ten_movable_flat_distractors_in_the_anchors_colours(env):
    kinds = set()
    for seed in range(4):
        env.reset(seed=seed)
        assert len(env.task.distractor_ids) == prg.DISTRACTORS == 10
        for index, body in enumerate(env.task.distractor_ids):
            assert env.is_dynamic(body)
            position, quat = assets.get_pose(env.client, body)
            assert geometry.quat_to_euler(quat)[:2] == pytest.approx((0.0, 0.0), abs=0.02)
            mass, friction = env.client.getDynamicsInfo(body, -1)[0:2]
            assert friction == pytest.approx(1.0)
            if _is_bowl(env, body):
                kinds.add("bowl")
                assert mass == pytest.approx(0.1) and position[2] == pytest.approx(0.0, abs=2e-3)
                assert _is_color(env, body, prg.DISTRACTOR_BOWL_COLORS[index])
            else:
                kinds.add("block")
                assert mass == pytest.approx(0.01) and position[2] == pytest.approx(0.02, abs=2e-3)
                assert _is_color(env, body, prg.DISTRACTOR_BLOCK_COLORS[index])
    assert kinds == {"bowl", "block"}
    assert "green" not in prg.DISTRACTOR_BOWL_COLORS and "red" not in prg.DISTRACTOR_BLOCK_COLORS


def test_distractor_bowls_have_the_anchors_centre_of_mass(env):
    env.reset(seed=ENV_SEED)
    bowls = [body for body in env.task.distractor_ids if _is_bowl(env, body)]
    assert bowls
    local_position = env.client.getDynamicsInfo(bowls[0], -1)[3]
    assert local_position == pytest.approx(shapes.BOWL_CENTER_OF_MASS, abs=1e-6)


def test_bowl_origin_lies_off_its_cavity(env):
    """The anchor's mesh is centred 2.15 cm off the body origin; the seat is on the axis."""
    env.reset(seed=ENV_SEED)
    target, seat = env.task.target_poses[0], env.task.strict_target_poses[0]
    local = geometry.multiply_poses(geometry.invert_pose(target), seat)[0]
    assert local == pytest.approx([-0.0203, 0.0071, 0.0345], abs=1e-6)
    assert geometry.rotation_angle(
        geometry.quat_to_matrix(target[1]), geometry.quat_to_matrix(seat[1])
    ) == pytest.approx(0.0, abs=1e-6)


def test_a_cube_dropped_on_the_floor_of_a_bowl_is_seated(env):
    env.reset(seed=ENV_SEED)
    for index in range(len(env.task.target_poses)):
        _seated(env, index)
        reward, info = env.task.reward(env)
        assert reward == 1.0 and info["strict_success"] and info["target_index"] == index, info


@pytest.mark.parametrize(
    "offset",
    [(0.06, 0.0, 0.0), (0.0, -0.055, 0.0), (0.04, 0.04, 0.0)],
)
def test_a_cube_beside_the_bowl_fails(env, offset):
    env.reset(seed=ONE_BOWL_SEED)
    (target,) = env.task.target_poses
    teleport(env, (np.asarray(target[0]) + offset, target[1]))
    reward, info = env.task.reward(env)
    assert reward == 0.0 and not info["strict_success"], info


def test_the_anchors_check_ignores_height_and_orientation_the_strict_check_does_not(env):
    """A cube just above the rim, or held higher over the bowl at any orientation, passes the
    anchor's x-y check (within 5 cm of the bowl's origin) but is not seated."""
    env.reset(seed=ENV_SEED)
    target = env.task.target_poses[0]
    over_rim = in_frame(target, (0.0, 0.0, shapes.BOWL_HEIGHT + 0.02))
    above = (target[0] + np.array([0.01, 0.0, 0.15]), geometry.euler_to_quat(0.7, 0.0, 1.0))
    for pose in (over_rim, above):
        teleport(env, pose)
        reward, info = env.task.reward(env)
        assert reward == 1.0 and not info["strict_success"], info
    teleport(env, in_frame(env.task.strict_target_poses[0], roll=math.pi / 2, yaw=0.3))
    reward, info = env.task.reward(env)
    assert reward == 1.0 and info["strict_success"], info  # a cube on any face is seated


def test_tolerances():
    assert prg.PlaceRedInGreen.tolerance.position == 0.05  # the anchor's pos_eps
    assert prg.PlaceRedInGreen.tolerance.yaw is None  # the anchor's symmetry 0
    assert prg.PlaceRedInGreen.tolerance.roll_pitch is None
    strict = prg.PlaceRedInGreen.strict_tolerance
    assert strict.position == 0.025 and strict.tilt is None and strict.yaw is None


def test_sampling_regions_are_the_anchors_eroded_workspace():
    assert math.isclose(prg.BOWL_CLEARANCE, 0.0849, abs_tol=1e-4)  # half the 0.12 x 0.12 diagonal
    assert math.isclose(prg.CUBE_CLEARANCE, 0.0283, abs_tol=1e-4)  # half the 0.04 x 0.04 diagonal
    assert np.allclose(prg.BOWL_REGION, [[0.3349, 0.6651], [-0.4151, 0.4151]], atol=1e-4)
    assert np.allclose(prg.CUBE_REGION, [[0.2783, 0.7217], [-0.4717, 0.4717]], atol=1e-4)


def test_challenging_bowls_are_tilted_beyond_the_training_range():
    env = make_env(TASK, "challenging")
    try:
        for seed in range(3):
            env.reset(seed=seed)
            for target in env.task.target_poses:
                roll, pitch, _ = geometry.quat_to_euler(target[1])
                assert math.pi / 6 <= max(abs(roll), abs(pitch)) <= math.pi / 4 + 1e-9
                assert target[0][2] == pytest.approx(0.03)
    finally:
        env.close()


@pytest.mark.parametrize("setting,seed", [("normal", 5), ("challenging", 6), ("flat", 7)])
def test_oracle_seats_the_cube(setting, seed):
    env = make_env(TASK, setting)
    try:
        env.reset(seed=seed)
        _, reward, terminated, _, info = env.step(env.task.oracle(env))
    finally:
        env.close()
    assert reward == 1.0 and terminated and info["strict_success"], info
    assert info["failure"] is None


def test_the_arm_reaches_every_pick_point_of_the_cube():
    """The oracle may pick anywhere on the cube's top face: the arm reaches all of it."""
    assert_oracle_reachable(TASK, "flat", range(16, 20))
