"""The success checks at their edges: every limit of every task's two checks (the table of
docs/conventions.md, "Tasks, settings and success", written out here) probed just inside (0.95x)
and just outside (1.05x), on both sides; and yaw errors measured across the wrap at +-pi and
modulo a shape's symmetry."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim.tasks import POSE_ERROR_KEYS, TASKS, pose_error_text
from nerf_transporter.sim.tasks.base import box_corners
from tests.helpers.tasks import in_frame

INSIDE, OUTSIDE = 0.95, 1.05
DEG_15, DEG_22_5 = math.radians(15), math.radians(22.5)
# task -> the documented limits of its anchor check (x-y m, yaw, roll and pitch; None: free) and
# of its strict check (3-D m, tilt, yaw; None: free)
ANCHOR_LIMITS = {
    "block-insertion": {"position": 0.02, "yaw": DEG_15, "roll_pitch": None},
    "place-red-in-green": {"position": 0.05, "yaw": None, "roll_pitch": None},
    "hanging-disks": {"position": 0.02, "yaw": None, "roll_pitch": DEG_22_5},
    "stacking-kits": {"position": 0.02, "yaw": DEG_22_5, "roll_pitch": DEG_22_5},
}
STRICT_LIMITS = {
    "block-insertion": {"position": 0.02, "tilt": DEG_15, "yaw": DEG_15},
    "place-red-in-green": {"position": 0.025, "tilt": None, "yaw": None},
    "hanging-disks": {"position": 0.02, "tilt": DEG_15, "yaw": None},
    "stacking-kits": {"position": 0.015, "tilt": DEG_15, "yaw": DEG_15},
}
# a target tilted and turned as a Normal target may be, away from any wrap
TARGET: Pose = (np.array([0.5, -0.1, 0.05]), geometry.euler_to_quat(0.2, -0.15, 1.0))
SIDES = (1.0, -1.0)


def _euler_shifted(pose: Pose, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> Pose:
    """`pose` with (roll, pitch, yaw) added to its eulerXYZ angles (what the anchor compares)."""
    euler = np.add(geometry.quat_to_euler(pose[1]), (roll, pitch, yaw))
    return pose[0], geometry.euler_to_quat(*euler)


def _moved(pose: Pose, offset) -> Pose:
    return np.asarray(pose[0]) + np.asarray(offset, dtype=float), pose[1]


def _anchor_success(task: str, pose: Pose, target: Pose = TARGET) -> bool:
    return TASKS[task].tolerance.check(pose, target)["success"]


def _strict_success(task: str, pose: Pose, target: Pose = TARGET) -> bool:
    return TASKS[task].strict_tolerance.check(pose, target)["success"]


@pytest.mark.parametrize("task", sorted(TASKS))
def test_the_documented_limits_are_the_tasks(task):
    """The table covers every task; its free angles are free in the task's checks too."""
    assert set(ANCHOR_LIMITS) == set(STRICT_LIMITS) == set(TASKS)
    anchor, strict = TASKS[task].tolerance, TASKS[task].strict_tolerance
    assert (anchor.yaw is None, anchor.roll_pitch is None) == (
        ANCHOR_LIMITS[task]["yaw"] is None,
        ANCHOR_LIMITS[task]["roll_pitch"] is None,
    )
    assert (strict.tilt is None, strict.yaw is None) == (
        STRICT_LIMITS[task]["tilt"] is None,
        STRICT_LIMITS[task]["yaw"] is None,
    )


@pytest.mark.parametrize("task", sorted(TASKS))
def test_anchor_position_limit_in_x_y_both_sides(task):
    limit = ANCHOR_LIMITS[task]["position"]
    for sign in SIDES:
        for direction in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.6, -0.8, 0.0)):
            step = sign * np.asarray(direction) * limit
            assert _anchor_success(task, _moved(TARGET, INSIDE * step)), (sign, direction)
            assert not _anchor_success(task, _moved(TARGET, OUTSIDE * step)), (sign, direction)
        # the anchor never judges height
        assert _anchor_success(task, _moved(TARGET, (0.0, 0.0, sign * 10 * limit)))


@pytest.mark.parametrize("task", sorted(TASKS))
def test_anchor_angle_limits_both_sides(task):
    limits = ANCHOR_LIMITS[task]
    for axis, limit in (
        ("yaw", limits["yaw"]),
        ("roll", limits["roll_pitch"]),
        ("pitch", limits["roll_pitch"]),
    ):
        for sign in SIDES:
            if limit is None:  # free: twice the widest limit passes
                assert _anchor_success(task, _euler_shifted(TARGET, **{axis: sign * 0.8})), axis
                continue
            inside = _euler_shifted(TARGET, **{axis: sign * INSIDE * limit})
            outside = _euler_shifted(TARGET, **{axis: sign * OUTSIDE * limit})
            assert _anchor_success(task, inside), (axis, sign)
            assert not _anchor_success(task, outside), (axis, sign)


@pytest.mark.parametrize("task", sorted(TASKS))
def test_strict_position_limit_in_3_d_both_sides(task):
    limit = STRICT_LIMITS[task]["position"]
    for sign in SIDES:
        for direction in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (0.0, 0.6, 0.8)):
            step = sign * np.asarray(direction) * limit
            assert _strict_success(task, in_frame(TARGET, INSIDE * step)), (sign, direction)
            assert not _strict_success(task, in_frame(TARGET, OUTSIDE * step)), (sign, direction)


@pytest.mark.parametrize("task", sorted(TASKS))
def test_strict_tilt_and_yaw_limits_both_sides(task):
    limits = STRICT_LIMITS[task]
    for axis, limit in (
        ("roll", limits["tilt"]),
        ("pitch", limits["tilt"]),
        ("yaw", limits["yaw"]),
    ):
        for sign in SIDES:
            if limit is None:  # free
                assert _strict_success(task, in_frame(TARGET, **{axis: sign * 1.2})), axis
                continue
            assert _strict_success(task, in_frame(TARGET, **{axis: sign * INSIDE * limit}))
            assert not _strict_success(task, in_frame(TARGET, **{axis: sign * OUTSIDE * limit}))


@pytest.mark.parametrize("task", ["block-insertion", "stacking-kits"])
def test_anchor_yaw_error_is_measured_across_the_wrap(task):
    """A target turned to just under +pi and an object just past it (eulerXYZ yaw near -pi):
    their yaws differ by nearly 2 pi, their orientations by a few degrees."""
    limit = ANCHOR_LIMITS[task]["yaw"]
    for target_yaw in (math.pi - 0.1, -math.pi + 0.1):
        target = _euler_shifted(TARGET, yaw=target_yaw - geometry.quat_to_euler(TARGET[1])[2])
        toward_wrap = math.copysign(1.0, target_yaw)
        inside = _euler_shifted(target, yaw=toward_wrap * INSIDE * limit)
        outside = _euler_shifted(target, yaw=toward_wrap * OUTSIDE * limit)
        crossed = geometry.quat_to_euler(inside[1])[2]
        assert abs(crossed - target_yaw) > math.pi  # the eulerXYZ yaws lie across the wrap
        assert _anchor_success(task, inside, target), target_yaw
        assert not _anchor_success(task, outside, target), target_yaw
        check = TASKS[task].tolerance.check(inside, target)
        assert check["yaw_error"] == pytest.approx(INSIDE * limit, abs=1e-9)


@pytest.mark.parametrize("folds", [2, 4, 6])
def test_yaw_errors_fold_modulo_a_shapes_symmetry(folds):
    """stacking-kits' shapes: turned by a whole symmetry step (either way) is no turn; turned by
    one step plus a little, the little is the error."""
    period = 2 * math.pi / folds
    anchor = dataclasses.replace(TASKS["stacking-kits"].tolerance, yaw_period=period)
    strict = dataclasses.replace(TASKS["stacking-kits"].strict_tolerance, yaw_period=period)
    for sign in SIDES:
        for steps in (1, folds - 1):
            for fraction, expected in ((INSIDE, True), (OUTSIDE, False)):
                turn = sign * (steps * period - fraction * DEG_15)
                strict_check = strict.check(in_frame(TARGET, yaw=turn), TARGET)
                assert strict_check["success"] is expected, (sign, steps, fraction)
                assert strict_check["yaw_error"] == pytest.approx(fraction * DEG_15, abs=1e-9)
                turn = sign * (steps * period + fraction * DEG_22_5)
                anchor_check = anchor.check(_euler_shifted(TARGET, yaw=turn), TARGET)
                assert anchor_check["success"] is expected, (sign, steps, fraction)
        half_turn = in_frame(TARGET, yaw=sign * period / 2)  # the farthest a yaw can be
        assert strict.check(half_turn, TARGET)["yaw_error"] == pytest.approx(period / 2)


@pytest.mark.parametrize("task", sorted(TASKS))
def test_a_position_error_of_exactly_the_limit_fails_the_anchor_and_passes_the_strict_check(task):
    """The anchor's limits are bounds from below (Ravens' `<`), the strict check's inclusive."""
    upright = np.array([0.0, 0.0, 0.0, 1.0])
    origin: Pose = (np.zeros(3), upright)
    anchor, strict = TASKS[task].tolerance.position, TASKS[task].strict_tolerance.position
    assert not _anchor_success(task, (np.array([anchor, 0.0, 0.0]), upright), origin)
    assert _anchor_success(
        task, (np.array([0.0, math.nextafter(anchor, 0.0), 0.0]), upright), origin
    )
    assert _strict_success(task, (np.array([0.0, 0.0, strict]), upright), origin)
    assert not _strict_success(
        task, (np.array([math.nextafter(strict, 1.0), 0, 0]), upright), origin
    )


@pytest.mark.parametrize("task", sorted(TASKS))
def test_both_checks_report_the_errors_a_failure_is_explained_with(task):
    """What the episode records and the failure message print (`pose_error_text`)."""
    for check in (TASKS[task].tolerance.check, TASKS[task].strict_tolerance.check):
        errors = check(_moved(TARGET, (0.1, 0.0, 0.0)), TARGET)
        assert set(errors) == {"success", *POSE_ERROR_KEYS}
        assert pose_error_text(errors) == (
            "the object did not end at the target pose (position 10.0 cm, tilt 0.0 deg, "
            "yaw 0.0 deg)"
        )
    assert pose_error_text({"position_error": None}) == "the object did not end at the target pose"


def test_a_boxs_corners_are_its_centre_plus_and_minus_each_half_extent():
    corners = box_corners((0.01, 0.02, 0.03), center=(1.0, 2.0, 3.0))
    expected = {(x, y, z) for x in (0.99, 1.01) for y in (1.98, 2.02) for z in (2.97, 3.03)}
    assert corners.shape == (8, 3)
    assert {tuple(np.round(corner, 9)) for corner in corners} == expected
