import math

from nerf_transporter.sim.tasks import hanging_disks
from nerf_transporter.splits import split_seed
from tests.helpers.tasks import in_frame, teleport

TASK = "hanging-disks"
ENV_SEED = 4  # the scene of the `env` fixture (conftest.py)


def test_train_and_test_colours_are_disjoint(env):
    assert set(hanging_disks.TRAIN_COLORS).isdisjoint(hanging_disks.TEST_COLORS)
    for split, palette in (
        ("train", hanging_disks.TRAIN_COLORS),
        ("test", hanging_disks.TEST_COLORS),
    ):
        for index in range(4):
            env.reset(seed=split_seed(split, index))
            assert set(env.task.colors.values()) <= set(palette)


def test_reward_judges_the_hanging_point_and_tilt_but_not_yaw(env):
    env.reset(seed=4)
    target = env.task.target_poses[0]
    cases = [
        (in_frame(target), 1.0),
        (in_frame(target, yaw=2.0), 1.0),
        (in_frame(target, (0.01, 0.0, 0.0)), 1.0),
        (in_frame(target, (0.03, 0.0, 0.0)), 0.0),
        (in_frame(target, (0.0, 0.0, 0.03)), 0.0),
        (in_frame(target, roll=math.radians(20)), 0.0),
        (in_frame(target, pitch=math.radians(-20)), 0.0),
    ]
    for pose, expected in cases:
        teleport(env, pose)
        assert env.task.reward(env)[0] == expected
