"""The pick-and-place motion primitive with a 6-DoF approach along each pose's z axis.

The anchor's `PickPlace`. Pick: move above the pick pose (APPROACH metres along its z axis), descend
along -z until the suction tip touches something, grasp, lift back. Place: move to APPROACH metres
along the place pose's z axis, descend along it until the held object touches something, release at
once, retreat, return home. A descent has no lower limit at the pose: it goes on until contact, for
DESCENT_LIMIT metres past the pose at most (by then the table stops any descent). The place pose
therefore only sets the line of the descent. Every failure is returned as a reason string.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim.robot import HOME_JOINTS, Robot

APPROACH = 0.32  # m, distance of the pre-pick / pre-place pose along the pose's z axis
DESCENT_LIMIT = APPROACH  # m a descent may go past the pick or place pose before it times out
LINEAR_STEP = 0.001  # m per simulation step during straight-line motions (the anchor's 1 mm)
IK_SPACING = 0.01  # m between inverse-kinematics waypoints of a straight-line motion
JOINT_STEP = 0.01  # rad (norm over the joints) per simulation step: the anchor's `movej` speed


class Simulation(Protocol):
    """What a motion needs of the environment: the arm, a physics step and which bodies move."""

    robot: Robot

    def step_simulation(self, count: int = 1) -> None: ...

    def is_dynamic(self, body: int) -> bool: ...


class MotionFailure(Exception):
    """A motion could not be executed; the message is the failure reason."""


def offset_along_z(pose: Pose, distance: float) -> Pose:
    """`pose` moved by `distance` along its own z axis."""
    position, quat = pose
    axis = geometry.quat_to_matrix(quat)[:, 2]
    return np.asarray(position, dtype=float) + distance * axis, np.asarray(quat, dtype=float)


def _solve(env: Simulation, pose: Pose, what: str, seed: np.ndarray | None = None) -> np.ndarray:
    q = env.robot.solve_ik(pose, seed)
    if q is None:
        raise MotionFailure(f"unreachable: {what}")
    return q


def move_joints(env: Simulation, target: np.ndarray) -> None:
    """Joint-space interpolation from the current joints to `target`."""
    start = env.robot.joint_positions()
    count = max(1, int(np.ceil(geometry.norm(target - start) / JOINT_STEP)))
    for k in range(1, count + 1):
        env.robot.drive(start + (target - start) * k / count)
        env.step_simulation()


def move_linear(env: Simulation, start: Pose, end: Pose, what: str, stop=None) -> bool:
    """Straight-line motion of the tip from `start` to `end` (orientation of `end`); returns True
    when `stop()` became true on the way (the motion then ends there). Inverse kinematics is solved
    every IK_SPACING metres and joint-interpolated in between (sub-millimetre deviation)."""
    start_position, end_position = (
        np.asarray(start[0], dtype=float),
        np.asarray(end[0], dtype=float),
    )
    distance = geometry.norm(end_position - start_position)
    waypoints = max(1, int(np.ceil(distance / IK_SPACING)))
    substeps = max(1, int(round(IK_SPACING / LINEAR_STEP)))
    previous = env.robot.joint_positions()
    for k in range(1, waypoints + 1):
        position = start_position + (end_position - start_position) * k / waypoints
        target = _solve(env, (position, end[1]), what, previous)
        for j in range(1, substeps + 1):
            env.robot.drive(previous + (target - previous) * j / substeps)
            env.step_simulation()
            if stop is not None and stop():
                return True
        previous = target
    return False


def pick_and_place(env: Simulation, pick: Pose, place: Pose) -> str | None:
    """Execute one pick and place; returns None on completion or the reason it failed."""
    try:
        _pick_and_place(env, _normalised(pick), _normalised(place))
    except MotionFailure as failure:
        env.robot.release()
        return str(failure)
    return None


def _normalised(pose: Pose) -> Pose:
    position = np.asarray(pose[0], dtype=float).reshape(3)
    quat = np.asarray(pose[1], dtype=float).reshape(4)
    norm = geometry.norm(quat)
    if not np.isfinite(norm) or norm < 1e-6 or not np.all(np.isfinite(position)):
        raise MotionFailure("invalid pose: zero or non-finite quaternion or position")
    return position, quat / norm


def _pick_and_place(env: Simulation, pick: Pose, place: Pose) -> None:
    robot = env.robot
    pre_pick, pre_place = offset_along_z(pick, APPROACH), offset_along_z(place, APPROACH)
    checks = {
        "pick pose": pick,
        "pre-pick pose": pre_pick,
        "place pose": place,
        "pre-place pose": pre_place,
    }
    for what, pose in checks.items():
        _solve(env, pose, what, HOME_JOINTS)

    move_joints(env, _solve(env, pre_pick, "pre-pick pose", HOME_JOINTS))
    if not move_linear(
        env, pre_pick, offset_along_z(pick, -DESCENT_LIMIT), "pick descent", robot.touching
    ):
        raise MotionFailure("timeout: no contact while descending to the pick pose")
    graspable = [body for body in robot.touching() if env.is_dynamic(body)]
    if not graspable:
        raise MotionFailure("pick: the suction tip touched no movable object")
    robot.activate(graspable[0])
    move_linear(env, robot.tip_pose(), pre_pick, "lift")

    move_joints(env, _solve(env, pre_place, "pre-place pose", HOME_JOINTS))
    if not move_linear(
        env, pre_place, offset_along_z(place, -DESCENT_LIMIT), "place descent", robot.held_touching
    ):
        raise MotionFailure("timeout: the held object touched nothing while descending to place")
    robot.release()
    move_linear(env, robot.tip_pose(), pre_place, "retreat")
    move_joints(env, HOME_JOINTS)
