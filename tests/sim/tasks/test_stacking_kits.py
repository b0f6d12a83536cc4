import math

from nerf_transporter.sim import shapes
from nerf_transporter.splits import split_seed
from tests.helpers.tasks import in_frame, teleport

TASK = "stacking-kits"
ENV_SEED = 6  # the scene of the `env` fixture (conftest.py)


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


def test_reward_tolerances(env):
    env.reset(seed=6)
    target = env.task.target_poses[0]
    cases = [
        (in_frame(target), 1.0),
        (in_frame(target, (0.01, 0.0, 0.0)), 1.0),
        (in_frame(target, (0.025, 0.0, 0.0)), 0.0),
        (in_frame(target, (0.0, 0.0, 0.025)), 0.0),
        (in_frame(target, roll=math.radians(20)), 0.0),
        (in_frame(target, yaw=math.radians(10)), 1.0),
    ]
    for pose, expected in cases:
        teleport(env, pose)
        assert env.task.reward(env)[0] == expected


def test_yaw_is_judged_modulo_the_shape_symmetry(env):
    _first_seed_with_symmetry(env, lambda order: order == 1)
    target = env.task.target_poses[0]
    teleport(env, in_frame(target, yaw=math.radians(20)))
    assert env.task.reward(env)[0] == 0.0
    teleport(env, in_frame(target, yaw=math.pi))
    assert env.task.reward(env)[0] == 0.0

    _first_seed_with_symmetry(env, lambda order: 2 <= order <= 8)
    target, period = env.task.target_poses[0], env.task.shape.yaw_period
    teleport(env, in_frame(target, yaw=period))
    assert env.task.reward(env)[0] == 1.0
    teleport(env, in_frame(target, yaw=period / 2))
    assert env.task.reward(env)[0] == 0.0
