import math

import numpy as np
import pytest

from nerf_transporter import geometry
from nerf_transporter.sim import make_env
from nerf_transporter.sim.primitives import APPROACH, offset_along_z
from nerf_transporter.sim.robot import HOME_JOINTS
from nerf_transporter.sim.tasks import block_insertion
from nerf_transporter.sim.tasks.base import SETTINGS
from tests.helpers.tasks import in_frame, teleport

TASK = "block-insertion"
ENV_SEED = 3  # the scene of the `env` fixture (conftest.py)
BOX = 3  # PyBullet's GEOM_BOX


def _boxes(env, body: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(full size, centre) of every collision box of a loaded body, in its link frame."""
    shapes = env.client.getCollisionShapeData(body, -1)
    assert all(shape[2] == BOX for shape in shapes)
    return [(np.array(shape[3]), np.array(shape[5])) for shape in shapes]


def _walls_and_pad(env) -> tuple[list, tuple]:
    boxes = _boxes(env, env.task.target_ids[0])
    pads = [box for box in boxes if box[0][2] < 0.01]
    assert len(pads) == 1
    return [box for box in boxes if box[0][2] >= 0.01], pads[0]


def test_the_block_is_the_anchors_ell(env):
    """Two 8 x 3 x 4 cm boxes offset 2.5 cm along x and along y, 0.1 kg, friction 0.3, centre of
    mass at the corner square's centre (the origin)."""
    boxes = sorted(_boxes(env, env.task.object_id), key=lambda box: -box[1][0])
    assert np.allclose(boxes[0][0], (0.08, 0.03, 0.04)) and np.allclose(boxes[0][1], (0.025, 0, 0))
    assert np.allclose(boxes[1][0], (0.03, 0.08, 0.04)) and np.allclose(boxes[1][1], (0, 0.025, 0))
    mass, friction, _, com, *_ = env.client.getDynamicsInfo(env.task.object_id, -1)
    assert (mass, friction) == pytest.approx((0.1, 0.3))
    assert np.allclose(com, 0.0)


def test_fixture_walls_are_2_mm_thick_and_as_tall_as_the_block(env):
    walls, _ = _walls_and_pad(env)
    assert len(walls) == 6
    for size, centre in walls:
        assert min(size) == pytest.approx(0.002)  # thickness
        assert size[2] == pytest.approx(0.04) == block_insertion.BLOCK_HEIGHT
        assert centre[2] == pytest.approx(0.0)  # spanning the block's own -2..2 cm
    _, friction, *_ = env.client.getDynamicsInfo(env.task.target_ids[0], -1)
    assert friction == pytest.approx(0.3)


def test_the_channels_leave_9_mm_per_side(env):
    """Every edge of the block's outline faces a wall whose channel side lies 9 mm out: 48 mm
    channels for the 30 mm arms, 98 mm long for the 80 mm ones."""
    walls, _ = _walls_and_pad(env)
    outline = block_insertion.block_outline()
    for start, end in zip(outline, np.roll(outline, -1, axis=0), strict=True):
        direction = (end - start) / np.linalg.norm(end - start)
        outward = np.array([direction[1], -direction[0]])
        gaps = []
        for size, centre in walls:
            thickness_axis = int(np.argmin(size[:2]))
            if abs(outward[thickness_axis]) < 0.5:
                continue  # not parallel to this edge
            face = centre[:2] @ outward - size[thickness_axis] / 2
            along = (centre[:2] - start) @ direction
            if face > start @ outward and -0.02 <= along <= np.linalg.norm(end - start) + 0.02:
                gaps.append(face - start @ outward)
        assert min(gaps) == pytest.approx(0.009), (start, end)


def test_the_only_floor_is_a_small_pad_under_the_corner(env):
    """20 x 20 x 1 mm, centred 20 mm below the origin: a centred block stands on it 0.5 mm
    above the fixture's origin (the strict target)."""
    _, (size, centre) = _walls_and_pad(env)
    assert np.allclose(size, (0.02, 0.02, 0.001))
    assert np.allclose(centre, (0.0, 0.0, -0.02))
    seat, _ = block_insertion.seat_offset()
    assert np.allclose(seat, (0.0, 0.0, 0.0005))


@pytest.mark.parametrize("setting", SETTINGS)
def test_fixture_origin_is_5_cm_high_whatever_the_tilt(setting):
    environment = make_env(TASK, setting)
    for seed in range(6):
        environment.reset(seed=seed)
        target = environment.task.target_poses[0]
        position, _ = environment.client.getBasePositionAndOrientation(
            environment.task.target_ids[0]
        )
        assert target[0][2] == pytest.approx(0.05) and position[2] == pytest.approx(0.05)
        strict = geometry.multiply_poses(target, block_insertion.seat_offset())
        assert np.allclose(environment.task.strict_target_poses[0][0], strict[0])
    environment.close()


def test_the_block_starts_flat_on_the_table_clear_of_the_fixture(env):
    for seed in range(6):
        env.reset(seed=seed)
        block = env.task.object_pose(env)
        assert block[0][2] == pytest.approx(block_insertion.BLOCK_HEIGHT / 2, abs=1e-3)
        assert not env.client.getContactPoints(env.task.object_id, env.task.target_ids[0])
        for value, (low, high) in zip(block[0][:2], block_insertion.REGION, strict=True):
            assert low <= value <= high


@pytest.mark.parametrize(("setting", "seed"), [("normal", 3), ("challenging", 7), ("flat", 5)])
def test_a_block_seated_in_the_fixture_succeeds_by_both_checks(setting, seed):
    environment = make_env(TASK, setting)
    environment.reset(seed=seed)
    teleport(environment, environment.task.strict_target_poses[0])
    environment.step_simulation(240)  # let it slide onto the walls
    environment.settle()
    reward, info = environment.task.reward(environment)
    environment.close()
    assert reward == 1.0 and info["strict_success"], info


def test_misplaced_or_turned_blocks_fail(env):
    env.reset(seed=ENV_SEED)
    target = env.task.target_poses[0]
    world_offset = (np.asarray(target[0]) + (0.025, 0.0, 0.0), target[1])
    for pose in (world_offset, in_frame(target, yaw=math.radians(20))):
        teleport(env, pose)
        reward, info = env.task.reward(env)
        assert reward == 0.0 and not info["strict_success"]


def test_the_strict_check_also_judges_height_and_tilt(env):
    """The anchor reads x-y and yaw only: a block 3 cm above the fixture, or one tilted 20 deg
    in it, passes the anchor's check and fails the strict one."""
    env.reset(seed=ENV_SEED)
    target = env.task.target_poses[0]
    lifted = (np.asarray(target[0]) + (0.0, 0.0, 0.03), target[1])
    for pose in (lifted, in_frame(target, roll=math.radians(20))):
        teleport(env, pose)
        reward, info = env.task.reward(env)
        assert reward == 1.0 and not info["strict_success"], info


def test_a_block_left_on_the_table_fails(env):
    env.reset(seed=ENV_SEED)
    reward, info = env.task.reward(env)
    assert reward == 0.0 and not info["strict_success"]


@pytest.mark.parametrize("setting", SETTINGS)
def test_every_sampled_place_pose_is_reachable(setting):
    environment = make_env(TASK, setting)
    for seed in range(12):
        environment.reset(seed=1000 + seed)
        place = environment.task.oracle(environment)["place"]
        for pose in (place, offset_along_z(place, APPROACH)):
            assert environment.robot.solve_ik(pose, HOME_JOINTS) is not None, (setting, seed)
    environment.close()


def test_challenging_tilts_leave_the_training_range():
    environment = make_env(TASK, "challenging")
    for seed in range(10):
        environment.reset(seed=seed)
        roll, pitch, _ = geometry.quat_to_euler(environment.task.target_poses[0][1])
        assert math.pi / 6 <= max(abs(roll), abs(pitch)) <= math.pi / 4 + 1e-9
    environment.close()


@pytest.mark.parametrize(("setting", "seed"), [("normal", 5), ("challenging", 6), ("flat", 7)])
def test_oracle_solves_an_episode(setting, seed):
    environment = make_env(TASK, setting)
    environment.reset(seed=seed)
    _, reward, terminated, _, info = environment.step(environment.task.oracle(environment))
    environment.close()
    assert reward == 1.0 and terminated, info
    assert info["failure"] is None


def test_slot_is_visible_in_colour(env):
    """An RGB-only policy must see the fixture: in the view along its normal the pad is dark,
    and from above its pixels are darker than the table's."""
    env.reset(seed=ENV_SEED)
    target = env.task.target_poses[0]
    roll, pitch, _ = geometry.quat_to_euler(target[1])
    colour, _ = env.render_orthographic(roll, pitch)
    view = geometry.tilt_matrix(roll, pitch)
    pad = np.asarray(target[0]) + geometry.quat_to_matrix(target[1]) @ (0.0, 0.0, -0.0195)
    (row, col), _ = geometry.world_to_view_pixel(pad, view)
    table = colour[-5, -5].astype(float).sum()
    assert colour[int(round(row)), int(round(col))].astype(float).sum() < 0.5 * table

    ids, _ = env.render_segmentation_top_down()
    top, _ = env.render_orthographic(0.0, 0.0)
    fixture = top[ids == env.task.target_ids[0]].astype(float).sum(axis=1)
    assert fixture.size > 50 and fixture.mean() < 0.7 * table
