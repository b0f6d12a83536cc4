"""What every task promises: determinism, reachable oracle actions, an object on target stays."""

import pytest

from nerf_transporter.sim import make_env
from nerf_transporter.sim.tasks import TASKS
from tests.helpers.tasks import assert_deterministic, assert_oracle_reachable, in_frame, teleport


@pytest.mark.parametrize("task", sorted(TASKS))
def test_same_seed_same_scene(task):
    assert_deterministic(task, "normal", 20)


@pytest.mark.parametrize("setting", ["normal", "challenging"])
@pytest.mark.parametrize("task", sorted(set(TASKS) - {"block-insertion"}))
def test_oracle_actions_are_reachable(task, setting):
    """(block-insertion checks every sampled place pose instead, in its own module.)"""
    assert_oracle_reachable(task, setting, range(100, 106))


@pytest.mark.parametrize("setting", ["normal", "challenging"])
@pytest.mark.parametrize(
    ("task", "seed", "lift"), [("hanging-disks", 7, 0.01), ("stacking-kits", 9, 0.005)]
)
def test_an_object_released_just_above_its_target_settles_there(task, seed, lift, setting):
    env = make_env(task, setting)
    env.reset(seed=seed)
    teleport(env, in_frame(env.task.target_poses[0], (0.0, 0.0, lift)))
    env.settle()
    reward, info = env.task.reward(env)
    env.close()
    assert reward == 1.0, info
