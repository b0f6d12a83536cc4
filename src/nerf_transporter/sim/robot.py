"""UR5e arm with a suction tool, generated from the public Denavit-Hartenberg parameters.

The arm is position-driven (kinematic): joint states are set along a path and the simulator steps
between waypoints. A held object hangs on the suction tip by a fixed constraint and stays a dynamic
body (it keeps its momentum and can swing or tip against contacts), as the anchor's suction. Only the suction tip collides;
the other links are visual. The suction tip frame is the action frame: its z axis points away from
the object (an upright frame approaches from straight above).
"""

from __future__ import annotations

import math

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.geometry import Pose
from nerf_transporter.sim.assets import (
    COLORS,
    Cylinder,
    cached_file,
    collision_xml,
    inertial_xml,
    visual_xml,
)

# UR5e DH parameters (metres, radians): a_i, d_i, alpha_i.
DH_A = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)
DH_D = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)
DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
HOME_JOINTS = np.array([-1.0, -0.5, 0.5, -0.5, -0.5, 0.0]) * math.pi
JOINT_LIMITS = np.array([[-2 * math.pi, 2 * math.pi]] * 6)
JOINT_LIMITS[2] = (-math.pi, math.pi)
SUCTION_LENGTH = 0.08  # flange to suction tip (m)
SUCTION_RADIUS = 0.01


def _link_visuals(index: int) -> list[Cylinder]:
    """Primitive shapes of link `index` (1-6): a joint housing plus the offsets to the next joint."""
    radius = 0.06 if index <= 3 else 0.045
    parts = [Cylinder(radius, 0.12 if index <= 3 else 0.09, color=COLORS["dark_gray"])]
    a, d = DH_A[index - 1], DH_D[index - 1]
    if abs(d) > 1e-9:
        parts.append(Cylinder(radius * 0.75, abs(d), position=(0.0, 0.0, d / 2)))
    if abs(a) > 1e-9:
        parts.append(
            Cylinder(radius * 0.75, abs(a), position=(a / 2, 0.0, d), rpy=(0, math.pi / 2, 0))
        )
    return parts


def ur5e_urdf() -> str:
    """URDF text of the arm: base, six revolute joints (DH convention), flange, suction tool."""
    links, joints = [], []
    base_parts = [Cylinder(0.075, 0.09, position=(0, 0, 0.045), color=COLORS["dark_gray"])]
    links.append(("base_link", base_parts, []))
    for i in range(1, 7):
        links.append((f"link{i}", _link_visuals(i), []))
        if i == 1:
            xyz, rpy = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        else:
            xyz, rpy = (DH_A[i - 2], 0.0, DH_D[i - 2]), (DH_ALPHA[i - 2], 0.0, 0.0)
        low, high = JOINT_LIMITS[i - 1]
        parent = "base_link" if i == 1 else f"link{i - 1}"
        joints.append(
            f'<joint name="joint{i}" type="revolute"><parent link="{parent}"/>'
            f'<child link="link{i}"/>{_origin(xyz, rpy)}<axis xyz="0 0 1"/>'
            f'<limit lower="{low}" upper="{high}" effort="150" velocity="3.14"/></joint>'
        )
    tool_parts = [Cylinder(0.02, SUCTION_LENGTH, position=(0, 0, SUCTION_LENGTH / 2))]
    links.append(("tool", tool_parts, []))
    joints.append(
        '<joint name="flange" type="fixed"><parent link="link6"/><child link="tool"/>'
        f"{_origin((0.0, 0.0, DH_D[5]), (0.0, 0.0, 0.0))}</joint>"
    )
    tip = Cylinder(SUCTION_RADIUS, 0.01, position=(0, 0, 0.005), color=COLORS["dark_gray"])
    links.append(("suction_tip", [tip], [tip]))
    joints.append(
        '<joint name="suction" type="fixed"><parent link="tool"/><child link="suction_tip"/>'
        f"{_origin((0.0, 0.0, SUCTION_LENGTH), (math.pi, 0.0, 0.0))}</joint>"
    )
    body = []
    for name, visuals, collisions in links:
        xml = inertial_xml(0.5, (0, 0, 0), 1e-3)
        xml += "".join(visual_xml(part, COLORS["gray"]) for part in visuals)
        xml += "".join(collision_xml(part) for part in collisions)
        body.append(f'<link name="{name}">{xml}</link>')
    return f'<?xml version="1.0"?>\n<robot name="ur5e">{"".join(body)}{"".join(joints)}</robot>\n'


def _dh(theta: float, i: int) -> np.ndarray:
    """DH transform of joint i: Rz(theta) Tz(d) Tx(a) Rx(alpha)."""
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(DH_ALPHA[i]), math.sin(DH_ALPHA[i])
    a, d = DH_A[i], DH_D[i]
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0, sa, ca, d],
            [0, 0, 0, 1.0],
        ]
    )


def dh_frames(q: np.ndarray) -> list[np.ndarray]:
    """Base-to-frame transforms of DH frames 1..6 (frame 6 is the flange)."""
    frames, transform = [], np.eye(4)
    for i in range(6):
        transform = geometry.matmul(transform, _dh(q[i], i))
        frames.append(transform)
    return frames


def _inverse(transform: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (`geometry.invert_transform`)."""
    return geometry.invert_transform(transform)


_FLANGE_TO_TIP = np.eye(4)
_FLANGE_TO_TIP[:3, :3] = geometry.rot_x(math.pi)
_FLANGE_TO_TIP[2, 3] = SUCTION_LENGTH
_TIP_TO_FLANGE = _inverse(_FLANGE_TO_TIP)


def analytic_ik(flange: np.ndarray) -> list[np.ndarray]:
    """All (up to 8) closed-form solutions placing DH frame 6 at the 4x4 transform `flange`."""
    a2, a3, d4, d6 = DH_A[1], DH_A[2], DH_D[3], DH_D[5]
    wrist = geometry.matmul(flange, [0.0, 0.0, -d6, 1.0])
    radius = math.hypot(wrist[0], wrist[1])
    if radius < abs(d4):
        return []
    inverse = _inverse(flange)
    solutions = []
    for sign1 in (1, -1):
        t1 = math.atan2(wrist[1], wrist[0]) + sign1 * math.acos(d4 / radius) + math.pi / 2
        s1, c1 = math.sin(t1), math.cos(t1)
        c5 = (flange[0, 3] * s1 - flange[1, 3] * c1 - d4) / d6
        if abs(c5) > 1:
            continue
        for sign5 in (1, -1):
            t5 = sign5 * math.acos(c5)
            s5 = math.sin(t5)
            if abs(s5) < 1e-9:
                t6 = 0.0  # wrist singularity: any t6 works, joint 4 absorbs it
            else:
                t6 = math.atan2(
                    (-inverse[1, 0] * s1 + inverse[1, 1] * c1) / s5,
                    (inverse[0, 0] * s1 - inverse[0, 1] * c1) / s5,
                )
            t14 = geometry.matmul(
                geometry.matmul(_inverse(_dh(t1, 0)), flange),
                _inverse(geometry.matmul(_dh(t5, 4), _dh(t6, 5))),
            )
            px, py = t14[0, 3], t14[1, 3]
            c3 = (px * px + py * py - a2 * a2 - a3 * a3) / (2 * a2 * a3)
            if abs(c3) > 1:
                continue
            for sign3 in (1, -1):
                t3 = sign3 * math.acos(c3)
                t2 = math.atan2(py, px) - math.atan2(a3 * math.sin(t3), a2 + a3 * math.cos(t3))
                t34 = geometry.matmul(_inverse(geometry.matmul(_dh(t2, 1), _dh(t3, 2))), t14)
                t4 = math.atan2(t34[1, 0], t34[0, 0])
                solutions.append(np.array([t1, t2, t3, t4, t5, t6]))
    return solutions


def _nearest_in_limits(q: np.ndarray, reference: np.ndarray) -> np.ndarray | None:
    """Shift each angle by multiples of 2 pi to be nearest `reference` within the joint limits."""
    angles = reference + (q - reference + math.pi) % (2 * math.pi) - math.pi
    angles = np.where(angles > JOINT_LIMITS[:, 1], angles - 2 * math.pi, angles)
    angles = np.where(angles < JOINT_LIMITS[:, 0], angles + 2 * math.pi, angles)
    if np.any(angles < JOINT_LIMITS[:, 0]) or np.any(angles > JOINT_LIMITS[:, 1]):
        return None
    return angles


def _origin(xyz, rpy) -> str:
    return '<origin xyz="{:.6f} {:.6f} {:.6f}" rpy="{:.6f} {:.6f} {:.6f}"/>'.format(*xyz, *rpy)


class Robot:
    """The arm in one simulator client: joints, forward/inverse kinematics and the suction gripper."""

    def __init__(self, client) -> None:
        self.client = client
        path = cached_file("ur5e", ".urdf", ur5e_urdf())
        self.id = client.loadURDF(str(path), useFixedBase=True)
        names = {
            client.getJointInfo(self.id, j)[1].decode(): j
            for j in range(client.getNumJoints(self.id))
        }
        self.joints = [names[f"joint{i}"] for i in range(1, 7)]
        self.tip_link = names["suction"]
        for link in range(-1, client.getNumJoints(self.id)):
            if link != self.tip_link:
                client.setCollisionFilterGroupMask(self.id, link, 0, 0)
        self.grasp_constraint: int | None = None
        self.held_body: int | None = None
        self.set_joints(HOME_JOINTS)

    # -- kinematics ------------------------------------------------------------------------------

    def joint_positions(self) -> np.ndarray:
        return np.array([s[0] for s in self.client.getJointStates(self.id, self.joints)])

    def set_joints(self, q: np.ndarray) -> None:
        for joint, value in zip(self.joints, q, strict=True):
            self.client.resetJointState(self.id, joint, float(value), 0.0)

    def drive(self, q: np.ndarray) -> None:
        """Put the arm at `q` (motors hold it there); the suction constraint carries the held
        object."""
        self.set_joints(q)
        self.client.setJointMotorControlArray(
            self.id,
            self.joints,
            self.client.POSITION_CONTROL,
            targetPositions=list(q),
            forces=[500.0] * 6,
        )

    def tip_pose(self) -> Pose:
        state = self.client.getLinkState(self.id, self.tip_link, computeForwardKinematics=True)
        return np.array(state[4]), np.array(state[5])

    def solve_ik(self, pose: Pose, seed: np.ndarray | None = None) -> np.ndarray | None:
        """Joint angles that put the suction tip at `pose` (closest to `seed`, default the current
        joints), or None when no solution keeps the arm above the table within its joint limits."""
        reference = self.joint_positions() if seed is None else np.asarray(seed, dtype=float)
        flange = geometry.matmul(geometry.pose_to_matrix(pose), _TIP_TO_FLANGE)
        candidates = [_nearest_in_limits(q, reference) for q in analytic_ik(flange)]
        candidates = [q for q in candidates if q is not None]
        candidates.sort(key=lambda q: float(np.abs(q - reference).sum()))
        for q in candidates:
            if min(frame[2, 3] for frame in dh_frames(q)[2:]) >= 0.01:
                return q
        return None

    # -- suction -----------------------------------------------------------------------------------

    def touching(self) -> list[int]:
        """Bodies in contact with the suction tip (the held body excluded)."""
        contacts = self.client.getContactPoints(bodyA=self.id, linkIndexA=self.tip_link)
        return sorted({c[2] for c in contacts if c[2] != self.held_body})

    def held_touching(self) -> list[int]:
        """Bodies the held object touches (the robot excluded)."""
        if self.held_body is None:
            return []
        contacts = self.client.getContactPoints(bodyA=self.held_body)
        return sorted({c[2] for c in contacts if c[2] != self.id})

    def activate(self, body: int) -> None:
        """Attach `body` to the suction tip with a fixed constraint at their current relative pose."""
        tip_pos, tip_quat = self.tip_pose()
        body_pos, body_quat = self.client.getBasePositionAndOrientation(body)
        local_pos, local_quat = self.client.multiplyTransforms(
            *self.client.invertTransform(tip_pos, tip_quat), body_pos, body_quat
        )
        self.grasp_constraint = self.client.createConstraint(
            parentBodyUniqueId=self.id,
            parentLinkIndex=self.tip_link,
            childBodyUniqueId=body,
            childLinkIndex=-1,
            jointType=self.client.JOINT_FIXED,
            jointAxis=(0, 0, 0),
            parentFramePosition=local_pos,
            childFramePosition=(0, 0, 0),
            parentFrameOrientation=local_quat,
            childFrameOrientation=(0, 0, 0, 1),
        )
        self.client.setCollisionFilterPair(self.id, body, self.tip_link, -1, 0)
        self.held_body = body

    def release(self) -> None:
        """Remove the suction constraint (no-op when nothing is held)."""
        if self.grasp_constraint is not None:
            self.client.removeConstraint(self.grasp_constraint)
            self.client.setCollisionFilterPair(self.id, self.held_body, self.tip_link, -1, 1)
        self.grasp_constraint = None
        self.held_body = None
