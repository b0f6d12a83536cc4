import math

import numpy as np
import pytest

from nerf_transporter import geometry
from nerf_transporter.sim import assets, make_env, shapes
from nerf_transporter.sim.tasks import hanging_disks
from nerf_transporter.sim.tasks.base import sampling_region
from nerf_transporter.splits import split_seed
from tests.helpers.tasks import in_frame, teleport

TASK = "hanging-disks"
ENV_SEED = 4  # the scene of the `env` fixture (conftest.py)
FLAT_STAND = (np.array([0.5, 0.0, 0.015]), np.array([0.0, 0.0, 0.0, 1.0]))
# PyBullet pads mesh collision shapes (the disk's pieces, and URDF cylinders, which it loads as
# meshes) by this margin, the anchor's assets alike; boxes keep their size
MESH_MARGIN = 0.001
PARKED_DISK = (np.array([0.32, 0.4, 0.005]), np.array([0.0, 0.0, 0.0, 1.0]))  # clear of FLAT_STAND


def _ray_hit(env, start, end) -> np.ndarray | None:
    """Where the segment start -> end first hits a collision shape (None: nowhere)."""
    body, _, _, position, _ = env.client.rayTest(list(start), list(end))[0]
    return None if body < 0 else np.array(position)


def _local(pose, point) -> np.ndarray:
    """`point` (world) in the frame of `pose`."""
    rotation = geometry.quat_to_matrix(pose[1])
    return rotation.T @ (np.asarray(point) - np.asarray(pose[0]))


def _world(pose, point) -> np.ndarray:
    """`point` given in the frame of `pose`, in the world."""
    return np.asarray(pose[0]) + geometry.quat_to_matrix(pose[1]) @ np.asarray(point, dtype=float)


def _set_stand(env, pose) -> None:
    """Move the stand to `pose` and the disk out of its way."""
    env.client.resetBasePositionAndOrientation(env.task.target_ids[0], pose[0], pose[1])
    teleport(env, PARKED_DISK)


def _drop(env, pose) -> None:
    """Release the disk at rest at `pose` and let it fall until the scene settles."""
    teleport(env, pose)
    env.step_simulation(10)  # set it moving: `settle` stops at once when nothing moves
    env.settle()


def test_stand_is_the_anchors_plate_and_rod(env):
    """Plate 0.1 x 0.1 x 0.01 m on the origin; rod of radius 5 mm and length 0.10 m centred
    0.03 m up, so its tip is 0.08 m above the origin and 75 mm above the plate's top."""
    env.reset(seed=ENV_SEED)
    _set_stand(env, FLAT_STAND)
    (plate,) = [
        s
        for s in env.client.getCollisionShapeData(env.task.target_ids[0], -1)
        if s[2] == env.client.GEOM_BOX
    ]
    assert plate[3] == pytest.approx((0.1, 0.1, 0.01)) and plate[5] == pytest.approx((0, 0, 0))
    assert shapes.rod_tip_height() == pytest.approx(0.08)
    assert shapes.rod_tip_height() - shapes.STAND_PLATE_SIZE[2] / 2 == pytest.approx(0.075)
    tip = _ray_hit(env, _world(FLAT_STAND, (0, 0, 0.2)), _world(FLAT_STAND, (0, 0, 0.0)))
    assert _local(FLAT_STAND, tip)[2] == pytest.approx(0.08 + MESH_MARGIN, abs=1e-4)
    for height in (0.01, 0.05, 0.075):  # the rod's side, all the way up
        side = _ray_hit(
            env, _world(FLAT_STAND, (0.1, 0, height)), _world(FLAT_STAND, (0, 0, height))
        )
        assert _local(FLAT_STAND, side)[0] == pytest.approx(0.005 + MESH_MARGIN, abs=1e-4)
    top = _ray_hit(
        env, _world(FLAT_STAND, (0.045, 0.045, 0.1)), _world(FLAT_STAND, (0.045, 0.045, -0.1))
    )
    assert _local(FLAT_STAND, top)[2] == pytest.approx(0.005, abs=1e-4)  # the plate's corner
    visual = {s[2]: s for s in env.client.getVisualShapeData(env.task.target_ids[0])}
    assert visual[env.client.GEOM_BOX][3] == pytest.approx((0.05, 0.05, 0.01))
    assert visual[env.client.GEOM_CYLINDER][3][:2] == pytest.approx((0.1, 0.005))
    assert visual[env.client.GEOM_CYLINDER][5] == pytest.approx((0, 0, 0.03))
    assert env.client.getDynamicsInfo(env.task.target_ids[0], -1)[1] == pytest.approx(0.5)


def test_disk_is_a_ring_with_a_real_hole(env):
    """Outer radius 45 mm, hole radius 22.5 mm, 10 mm thick; mass 0.1 kg, friction 1.0."""
    points = np.concatenate(shapes.disk_pieces())
    radii = np.linalg.norm(points[:, :2], axis=1)
    assert radii.min() == pytest.approx(0.0225) and radii.max() == pytest.approx(0.045)
    assert np.ptp(points[:, 2]) == pytest.approx(0.01) and points[:, 2].mean() == pytest.approx(0)
    env.reset(seed=ENV_SEED)
    disk = env.task.object_id
    assert env.client.getDynamicsInfo(disk, -1)[:2] == pytest.approx((0.1, 1.0))
    pose = (np.array([0.5, 0.3, 0.005]), np.array([0.0, 0.0, 0.0, 1.0]))
    teleport(env, pose)
    assert _ray_hit(env, _world(pose, (0, 0, 0.1)), _world(pose, (0, 0, 0.001))) is None
    rim = _ray_hit(env, _world(pose, (0.03, 0, 0.1)), _world(pose, (0.03, 0, 0.001)))
    assert _local(pose, rim)[2] == pytest.approx(0.005 + MESH_MARGIN, abs=1e-4)
    outer = _ray_hit(env, _world(pose, (0.1, 0, 0)), _world(pose, (0, 0, 0)))  # at a vertex
    assert _local(pose, outer)[0] == pytest.approx(0.045 + MESH_MARGIN, abs=1e-4)
    hole = _ray_hit(env, _world(pose, (0, 0, 0)), _world(pose, (0.1, 0, 0)))
    assert _local(pose, hole)[0] == pytest.approx(0.0225 - MESH_MARGIN, abs=1e-4)


@pytest.mark.parametrize("setting", ["normal", "challenging", "flat"])
def test_stand_origin_is_at_0_015_m_and_the_target_is_mid_rod(setting):
    env = make_env(TASK, setting)
    try:
        tilts = []
        for seed in range(6):
            env.reset(seed=seed)
            stand = assets.get_pose(env.client, env.task.target_ids[0])
            assert stand[0][2] == pytest.approx(0.015)
            (x0, x1), (y0, y1) = sampling_region(hanging_disks.STAND_FOOTPRINT)
            assert x0 <= stand[0][0] <= x1 and y0 <= stand[0][1] <= y1
            target, strict = env.task.target_poses[0], env.task.strict_target_poses[0]
            assert _local(stand, target[0]) == pytest.approx((0, 0, 0.03), abs=1e-6)
            assert _local(stand, strict[0]) == pytest.approx((0, 0, 0.01), abs=1e-6)
            for pose in (target, strict):
                assert geometry.quat_to_euler(pose[1]) == pytest.approx(
                    geometry.quat_to_euler(stand[1]), abs=1e-6
                )
            tilts.append(np.abs(geometry.quat_to_euler(stand[1])[:2]).max())
            disk = env.task.object_pose(env)
            assert disk[0][2] == pytest.approx(0.005, abs=1e-3)
            assert np.linalg.norm(disk[0][:2] - stand[0][:2]) >= 0.07 + 0.045
    finally:
        env.close()
    limit = {"normal": math.pi / 6, "challenging": math.pi / 4, "flat": 0.0}[setting]
    assert max(tilts) <= limit + 1e-6
    if setting == "challenging":
        assert min(tilts) >= math.pi / 6 - 1e-6


def test_the_stand_and_disk_are_drawn_from_the_anchors_eroded_free_space():
    """The anchor erodes the free pixels by a square of the sampling size's diagonal."""
    stand = sampling_region((0.12, 0.36))
    assert np.ravel(stand) == pytest.approx((0.4397, 0.5603, -0.3103, 0.3103), abs=1e-4)
    disk = sampling_region((0.08, 0.08))
    assert np.ravel(disk) == pytest.approx((0.3066, 0.6934, -0.4434, 0.4434), abs=1e-4)


@pytest.mark.parametrize("tilted", [False, True])
def test_a_disk_dropped_over_the_rod_slides_down_it(env, tilted):
    env.reset(seed=ENV_SEED)
    stand = assets.get_pose(env.client, env.task.target_ids[0]) if tilted else FLAT_STAND
    _set_stand(env, stand)
    above_tip = in_frame(stand, (0.0, 0.0, shapes.rod_tip_height() + 0.01))
    _drop(env, above_tip)
    end = _local(stand, env.task.object_pose(env)[0])
    if tilted:  # it ends low on the rod, on the plate or leaning on the table beside it
        assert end[2] < shapes.ROD_CENTRE_HEIGHT and np.linalg.norm(end[:2]) < 0.0175
    else:
        assert end == pytest.approx((0.0, 0.0, shapes.disk_rest_height()), abs=1.5e-3)
    if not tilted:  # the strict target is where a seated disk's origin ends
        strict = env.task.strict_tolerance.check(
            env.task.object_pose(env), in_frame(stand, (0, 0, shapes.disk_rest_height()))
        )
        assert strict["success"] and strict["position_error"] < 0.002


def test_a_disk_dropped_off_the_rod_does_not_thread_it(env):
    env.reset(seed=ENV_SEED)
    _set_stand(env, FLAT_STAND)
    _drop(env, in_frame(FLAT_STAND, (0.03, 0.0, shapes.rod_tip_height() + 0.01)))
    end = _local(FLAT_STAND, env.task.object_pose(env)[0])
    assert np.linalg.norm(end[:2]) > shapes.DISK_HOLE_RADIUS
    assert not env.task.reward(env)[1]["success"]


def _turned(pose, roll=0.0, pitch=0.0, yaw=0.0):
    """`pose` with (roll, pitch, yaw) added to its eulerXYZ angles (what the anchor compares)."""
    euler = np.add(geometry.quat_to_euler(pose[1]), (roll, pitch, yaw))
    return pose[0], geometry.euler_to_quat(*euler)


def test_reward_judges_x_y_and_roll_pitch_but_not_yaw_or_z(env):
    """The anchor's match_rp: x-y within 0.02 m of mid-rod, roll and pitch within 22.5 deg."""
    env.reset(seed=ENV_SEED)
    target = env.task.target_poses[0]
    up = (target[0] + np.array([0.0, 0.0, 0.05]), target[1])  # straight up: z is never judged
    cases = [
        (target, True),
        (up, True),
        (_turned(target, yaw=2.0), True),
        (in_frame(target, (0.012, 0.0, 0.0)), True),
        (in_frame(target, (0.03, 0.0, 0.0)), False),
        (_turned(target, roll=math.radians(20)), True),
        (_turned(target, roll=math.radians(25)), False),
        (_turned(target, pitch=math.radians(-25)), False),
    ]
    for pose, expected in cases:
        teleport(env, pose)
        assert env.task.reward(env)[1]["success"] is expected


def test_a_seated_disk_passes_both_checks_and_a_fallen_one_neither(env):
    env.reset(seed=ENV_SEED)
    target = env.task.target_poses[0]
    _drop(env, in_frame(target, (0.0, 0.0, 0.01)))
    reward, info = env.task.reward(env)
    assert reward == 1.0 and info["strict_success"], info
    off = in_frame(target, (0.07, 0.0, 0.02))  # dropped beside the stand
    _drop(env, off)
    reward, info = env.task.reward(env)
    assert reward == 0.0 and not info["strict_success"], info


def test_the_strict_check_is_stricter():
    """Passing the anchor's check but not the strict one: a disk stuck 5 cm up the rod (the
    anchor never judges height), or seated 20 deg off the plate (anchor 22.5, strict 15)."""
    task = hanging_disks.HangingDisks()
    stand = (np.array([0.5, 0.0, 0.015]), geometry.euler_to_quat(math.radians(20), 0.0, 1.0))
    target = in_frame(stand, (0, 0, shapes.ROD_CENTRE_HEIGHT))
    strict_target = in_frame(stand, (0, 0, shapes.disk_rest_height()))
    for pose in (in_frame(stand, (0, 0, 0.06)), in_frame(strict_target, roll=math.radians(20))):
        assert task.tolerance.check(pose, target)["success"]
        assert not task.strict_tolerance.check(pose, strict_target)["success"]
    assert task.strict_tolerance.check(in_frame(strict_target, yaw=2.5), strict_target)["success"]


def test_test_seeds_draw_the_anchors_evaluation_colours(env):
    train, test = hanging_disks.TRAIN_COLORS, hanging_disks.TEST_COLORS
    assert set(test) - set(train) == {"orange", "purple", "pink", "white"}  # never seen in training
    assert set(train) & set(test) == {"blue", "red", "green"}  # shared, as the anchor's are
    assert set(train) | set(test) <= set(assets.COLORS)
    for split, palette in (("train", train), ("validation", train), ("test", test)):
        for index in range(4):
            env.reset(seed=split_seed(split, index))
            assert env.task.colors["disk"] in palette
            assert env.task.colors["stand"] == "brown"


@pytest.mark.parametrize(("setting", "seed"), [("normal", 5), ("challenging", 6), ("flat", 7)])
def test_oracle_hangs_the_disk(setting, seed):
    """The oracle's pick and place, run by the arm: the disk ends on the rod, by both checks."""
    environment = make_env(TASK, setting)
    environment.reset(seed=seed)
    _, reward, terminated, _, info = environment.step(environment.task.oracle(environment))
    environment.close()
    assert reward == 1.0 and terminated, info
    assert info["failure"] is None and info["strict_success"], info
