import math

import pytest

from nerf_transporter.sim import make_env
from nerf_transporter.sim.tasks import hanging_disks
from nerf_transporter.splits import split_seed
from tests.helpers.tasks import assert_deterministic, assert_oracle_reachable, in_frame, teleport

TASK = "hanging-disks"


@pytest.fixture(scope="module")
def env():
    env = make_env(TASK, "normal")
    env.reset(seed=4)
    yield env
    env.close()


def test_same_seed_same_scene():
    assert_deterministic(TASK, "normal", 20)


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


@pytest.mark.parametrize("setting", ["normal", "challenging"])
def test_a_disk_on_the_rod_stays_hanging(setting):
    env = make_env(TASK, setting)
    env.reset(seed=7)
    teleport(env, in_frame(env.task.target_poses[0], (0.0, 0.0, 0.01)))
    env.settle()
    reward, info = env.task.reward(env)
    env.close()
    assert reward == 1.0, info


@pytest.mark.parametrize("setting", ["normal", "challenging"])
def test_oracle_actions_are_reachable(setting):
    assert_oracle_reachable(TASK, setting, range(100, 106))
