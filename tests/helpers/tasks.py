"""Checks shared by the task tests: determinism, reachability of oracle actions, teleporting."""

from __future__ import annotations

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim import make_env
from nerf_transporter.sim.primitives import APPROACH, offset_along_z
from nerf_transporter.sim.robot import HOME_JOINTS


def initial_state(task: str, setting: str, seed: int) -> np.ndarray:
    env = make_env(task, setting)
    try:
        env.reset(seed=seed)
        return env.task.state(env)
    finally:
        env.close()


def assert_deterministic(task: str, setting: str, seed: int) -> None:
    """Same seed, same initial poses; another seed, other poses."""
    first = initial_state(task, setting, seed)
    assert np.array_equal(first, initial_state(task, setting, seed))
    assert not np.allclose(first, initial_state(task, setting, seed + 2))


def assert_oracle_reachable(task: str, setting: str, seeds: range) -> None:
    """The arm reaches the pick and place poses of every oracle action and their approaches."""
    env = make_env(task, setting)
    try:
        for seed in seeds:
            env.reset(seed=seed)
            action = env.task.oracle(env)
            for name in ("pick", "place"):
                for pose in (action[name], offset_along_z(action[name], APPROACH)):
                    assert env.robot.solve_ik(pose, HOME_JOINTS) is not None, (seed, name)
    finally:
        env.close()


def in_frame(pose: Pose, offset=(0.0, 0.0, 0.0), roll=0.0, pitch=0.0, yaw=0.0) -> Pose:
    """`pose` moved by `offset` and rotated by (roll, pitch, yaw), both in its own frame."""
    local = (np.asarray(offset, dtype=float), geometry.euler_to_quat(roll, pitch, yaw))
    return geometry.multiply_poses(pose, local)


def teleport(env, pose: Pose) -> None:
    env.client.resetBasePositionAndOrientation(env.task.object_id, pose[0], pose[1])
