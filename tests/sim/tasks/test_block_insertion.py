import math

import numpy as np
import pytest

from nerf_transporter import geometry
from nerf_transporter.sim import make_env
from nerf_transporter.sim.assets import set_pose
from nerf_transporter.sim.primitives import APPROACH, offset_along_z
from nerf_transporter.sim.tasks.base import SETTINGS
from nerf_transporter.sim.tasks.block_insertion import ARM, CLEARANCE, SIZE, WALL


@pytest.fixture(scope="module")
def env():
    environment = make_env("block-insertion", "normal")
    yield environment
    environment.close()


def _shifted(pose, offset=(0.0, 0.0, 0.0), tilt=0.0):
    rotation = geometry.quat_to_matrix(pose[1]) @ geometry.rot_x(tilt)
    return np.asarray(pose[0]) + np.asarray(offset), geometry.matrix_to_quat(rotation)


def test_object_on_target_succeeds_and_settles_there(env):
    env.reset(seed=11)
    set_pose(env.client, env.task.object_id, env.task.target_poses[0])
    env.settle()
    reward, info = env.task.reward(env)
    assert reward == 1.0, info


@pytest.mark.parametrize(
    "offset,tilt",
    [((0.03, 0.0, 0.0), 0.0), ((0.0, 0.0, 0.03), 0.0), ((0.0, 0.0, 0.0), math.radians(20))],
)
def test_displaced_or_tilted_object_fails(env, offset, tilt):
    env.reset(seed=11)
    set_pose(env.client, env.task.object_id, _shifted(env.task.target_poses[0], offset, tilt))
    reward, _ = env.task.reward(env)
    assert reward == 0.0


@pytest.mark.parametrize("setting", SETTINGS)
def test_every_sampled_place_pose_is_reachable(setting):
    environment = make_env("block-insertion", setting)
    for seed in range(20):
        environment.reset(seed=1000 + seed)
        place = environment.task.oracle(environment)["place"]
        for pose in (place, offset_along_z(place, APPROACH)):
            assert environment.robot.solve_ik(pose) is not None, (setting, seed)
    environment.close()


def test_challenging_tilts_leave_the_training_range():
    environment = make_env("block-insertion", "challenging")
    for seed in range(10):
        environment.reset(seed=seed)
        roll, pitch, _ = geometry.quat_to_euler(environment.task.target_poses[0][1])
        assert math.pi / 6 <= max(abs(roll), abs(pitch)) <= math.pi / 4 + 1e-9
    environment.close()


@pytest.mark.parametrize("setting,seed", [("normal", 5), ("challenging", 6), ("flat", 7)])
def test_oracle_solves_an_episode(setting, seed):
    environment = make_env("block-insertion", setting)
    environment.reset(seed=seed)
    _, reward, terminated, _, info = environment.step(environment.task.oracle(environment))
    assert reward == 1.0 and terminated, info
    assert info["failure"] is None
    environment.close()


def test_slot_is_visible_in_colour():
    """An RGB-only policy must see the slot: its floor is darker than the wall tops around it."""
    env = make_env("block-insertion", "flat")
    try:
        env.reset(seed=3)
        colour, _ = env.render_orthographic(0.0, 0.0)
        target = geometry.pose_to_matrix(env.task.target_poses[0])
    finally:
        env.close()
    half, wall = SIZE / 2, (CLEARANCE + WALL / 2)
    # in the fixture frame: the corner of the L (slot floor) and the middle of two outer walls
    points = np.array(
        [[-half + ARM / 2, -half + ARM / 2, 0.0], [-half - wall, 0, 0], [0, -half - wall, 0]]
    )
    world = points @ target[:3, :3].T + target[:3, 3]
    rows, cols = np.round(geometry.world_to_pixel(world)).astype(int).T
    brightness = colour[rows, cols].astype(float).sum(axis=1)
    assert brightness[0] < 0.75 * brightness[1:].min(), brightness
