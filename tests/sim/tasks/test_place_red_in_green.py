import math

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.sim import make_env
from nerf_transporter.sim.tasks import place_red_in_green
from tests.helpers.tasks import in_frame, teleport

TASK = "place-red-in-green"
ENV_SEED = 12  # the scene of the `env` fixture (conftest.py)


def test_scene_has_green_bowls_and_ten_distractors(env):
    for seed in (0, 1, 2, 3):
        env.reset(seed=seed)
        task = env.task
        assert 1 <= len(task.target_poses) <= 3 == task.max_targets
        assert len(task.distractor_ids) == place_red_in_green.DISTRACTORS
        for body in task.target_ids:
            rgba = env.client.getVisualShapeData(body)[0][7]
            assert np.allclose(rgba[:3], place_red_in_green.assets.COLORS["green"][:3])
        for body in task.distractor_ids:
            rgba = env.client.getVisualShapeData(body)[0][7]
            assert not np.allclose(rgba[:3], place_red_in_green.assets.COLORS["green"][:3])
            assert not np.allclose(rgba[:3], place_red_in_green.assets.COLORS["red"][:3])


def test_reward_position_within_five_cm_any_orientation(env):
    env.reset(seed=12)
    for target in env.task.target_poses:
        teleport(env, target)
        assert env.task.reward(env)[0] == 1.0
        teleport(env, in_frame(target, (0.03, 0.0, 0.0), roll=math.radians(40), yaw=1.0))
        assert env.task.reward(env)[0] == 1.0
        teleport(env, in_frame(target, (0.0, 0.0, 0.07)))
        assert env.task.reward(env)[0] == 0.0


def test_a_cube_dropped_in_a_bowl_stays_there(env):
    env.reset(seed=5)
    target = env.task.target_poses[-1]
    teleport(env, in_frame(target, (0.0, 0.0, 0.01)))
    env.settle()
    reward, info = env.task.reward(env)
    assert reward == 1.0, info


def test_bowls_float_above_the_table(env):
    env.reset(seed=8)
    bowls = [
        body for body in env.task.target_ids + env.task.distractor_ids if not env.is_dynamic(body)
    ]
    assert len(bowls) > len(env.task.target_ids)
    for body in bowls:
        closest = env.client.getClosestPoints(body, env.table_id, 0.05)
        assert min((point[8] for point in closest), default=0.05) > 0.01


def test_challenging_bowls_are_tilted_beyond_the_training_range():
    env = make_env(TASK, "challenging")
    env.reset(seed=3)
    for target in env.task.target_poses:
        roll, pitch, _ = geometry.quat_to_euler(target[1])
        assert math.pi / 6 <= max(abs(roll), abs(pitch)) <= math.pi / 4 + 1e-9
    env.close()
