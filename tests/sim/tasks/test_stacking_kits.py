import math
from pathlib import Path

import numpy as np
import pytest

from nerf_transporter import geometry
from nerf_transporter.sim import assets, make_env, shapes
from nerf_transporter.splits import split_seed
from tests.helpers.tasks import in_frame, teleport

TASK = "stacking-kits"
ENV_SEED = 6  # the scene of the `env` fixture (conftest.py)


def _relative(env, body: int, frame: int):
    """Pose of `body` in the frame of `frame`."""
    client = env.client
    return geometry.multiply_poses(
        geometry.invert_pose(assets.get_pose(client, frame)), assets.get_pose(client, body)
    )


def _collision_files(env, body: int) -> list[str]:
    return [shape[4].decode() for shape in env.client.getCollisionShapeData(body, -1)]


def _obj_vertices(path: str) -> np.ndarray:
    lines = Path(path).read_text().splitlines()
    return np.array([[float(v) for v in line.split()[1:]] for line in lines if line[:2] == "v "])


def test_kit_is_the_anchors_thin_fixed_plate_at_a_fixed_height():
    env = make_env(TASK, "challenging")
    try:
        heights, tilts = [], []
        for seed in range(5):
            env.reset(seed=seed)
            kit = env.task.target_ids[0]
            (shape,) = env.client.getCollisionShapeData(kit, -1)
            assert shape[2] == env.client.GEOM_BOX
            assert np.allclose(shape[3], (0.1, 0.1, 0.005))
            mass, friction = env.client.getDynamicsInfo(kit, -1)[:2]
            assert (mass, friction) == (0.0, 1.0)  # fixed
            position, quat = assets.get_pose(env.client, kit)
            heights.append(position[2])
            tilts.append(max(map(abs, geometry.quat_to_euler(quat)[:2])))
        assert np.allclose(heights, 0.0325)
        assert max(tilts) > math.radians(30)  # Challenging tilts, origin still at 0.0325 m
    finally:
        env.close()


def test_the_target_is_a_fixed_dark_copy_of_the_object_on_the_kit(env):
    yaws = []
    for seed in range(0, 10, 2):
        env.reset(seed=seed)
        task = env.task
        kit, copy = task.target_ids
        assert _collision_files(env, copy) == _collision_files(env, task.object_id)
        visual = env.client.getVisualShapeData(copy)
        assert np.allclose(visual[0][7], (0.2, 0.2, 0.2, 1.0))
        mass, friction = env.client.getDynamicsInfo(copy, -1)[:2]
        assert (mass, friction) == (0.0, 2.0)  # fixed; friction 2 x 2 = 4 against the object
        position, quat = _relative(env, copy, kit)
        assert np.allclose(position, (0.0, 0.0, 0.0014), atol=1e-6)
        roll, pitch, yaw = geometry.quat_to_euler(quat)
        assert abs(roll) < 1e-6 and abs(pitch) < 1e-6  # tilted with the kit
        yaws.append(yaw)
        target = task.target_poses[0]
        assert np.allclose(target[0], assets.get_pose(env.client, copy)[0])
        stacked = geometry.multiply_poses(target, ((0.0, 0.0, 0.02), (0.0, 0.0, 0.0, 1.0)))
        assert np.allclose(task.strict_target_poses[0][0], stacked[0])
    assert np.ptp(yaws) > 1.0  # a random yaw on the kit


def test_object_is_the_anchors_size_mass_and_friction_resting_on_the_table(env):
    env.reset(seed=ENV_SEED)
    body = env.task.object_id
    vertices = np.concatenate([_obj_vertices(path) for path in _collision_files(env, body)])
    assert np.allclose(vertices[:, 2].min(), 0.0) and np.allclose(vertices[:, 2].max(), 0.02)
    assert np.ptp(vertices[:, :2], axis=0).max() == pytest.approx(0.057)  # the longer side
    position, quat = env.task.object_pose(env)
    assert position[2] == pytest.approx(0.0, abs=1e-3)  # origin on its bottom face
    assert max(map(abs, geometry.quat_to_euler(quat)[:2])) < 1e-3
    mass, friction = env.client.getDynamicsInfo(body, -1)[:2]
    assert (mass, friction) == (0.1, 2.0)


def test_test_seeds_use_unseen_shapes(env):
    for split, names in (("train", shapes.TRAIN_KIT_SHAPES), ("test", shapes.TEST_KIT_SHAPES)):
        seen = set()
        for index in range(8):
            env.reset(seed=split_seed(split, index))
            seen.add(env.task.shape.name)
        assert seen <= set(names)
        assert len(seen) > 1


def _first_seed_with_symmetry(env, wanted) -> None:
    for seed in range(0, 200, 2):
        env.reset(seed=seed)
        if wanted(env.task.shape.symmetry):
            return
    raise AssertionError("no seed with that symmetry")


def _turned(pose, roll=0.0, pitch=0.0):
    """`pose` with its eulerXYZ roll and pitch changed by these (what the anchor compares)."""
    euler = np.add(geometry.quat_to_euler(pose[1]), (roll, pitch, 0.0))
    return pose[0], geometry.euler_to_quat(*euler)


def _checks(env) -> tuple[bool, bool]:
    reward, info = env.task.reward(env)
    return reward == 1.0, info["strict_success"]


def test_an_object_stacked_on_the_copy_succeeds_and_stays(env):
    env.reset(seed=ENV_SEED)
    teleport(env, in_frame(env.task.strict_target_poses[0], (0.0, 0.0, 0.002)))
    env.settle()
    assert _checks(env) == (True, True)


def test_tilted_off_or_misplaced_objects_fail(env):
    env.reset(seed=ENV_SEED)
    stacked = env.task.strict_target_poses[0]
    cases = [
        _turned(stacked, roll=math.radians(25)),  # roll and pitch limits 22.5 deg
        _turned(stacked, pitch=math.radians(-25)),
        in_frame(stacked, (0.03, 0.0, 0.0)),
        (np.array([0.35, 0.4, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])),  # left on the table
    ]
    for pose in cases:
        teleport(env, pose)
        assert _checks(env) == (False, False), pose


def test_the_strict_check_is_stricter(env):
    _first_seed_with_symmetry(env, lambda order: order == 1)
    stacked = env.task.strict_target_poses[0]
    for pose in (
        in_frame(stacked, yaw=math.radians(20)),  # anchor: 22.5 deg; strict: 15 deg
        _turned(stacked, roll=math.radians(20)),
        (stacked[0] + np.array([0.0, 0.0, 0.03]), stacked[1]),  # 3 cm above: anchor ignores z
    ):
        teleport(env, pose)
        assert _checks(env) == (True, False)


def test_yaw_is_judged_modulo_the_shape_symmetry(env):
    _first_seed_with_symmetry(env, lambda order: order == 1)
    stacked = env.task.strict_target_poses[0]
    teleport(env, in_frame(stacked, yaw=math.pi))
    assert _checks(env) == (False, False)

    _first_seed_with_symmetry(env, lambda order: 2 <= order <= 6)  # half a period > 22.5 deg
    stacked, period = env.task.strict_target_poses[0], env.task.shape.yaw_period
    teleport(env, in_frame(stacked, yaw=period))
    assert _checks(env) == (True, True)
    teleport(env, in_frame(stacked, yaw=period / 2))
    assert _checks(env) == (False, False)


@pytest.mark.parametrize("setting", ["normal", "challenging"])
def test_the_oracle_stacks_the_object_on_the_copy(setting):
    env = make_env(TASK, setting)
    try:
        env.reset(seed=3)
        _, reward, _, _, info = env.step(env.task.oracle(env))
        assert reward == 1.0 and info["strict_success"], info
        # the object ends one thickness (plus PyBullet's contact margins) out along the normal
        along_normal = _relative(env, env.task.object_id, env.task.target_ids[1])[0]
        assert np.allclose(along_normal[:2], 0.0, atol=0.003)
        assert along_normal[2] == pytest.approx(0.022, abs=0.001)
    finally:
        env.close()
