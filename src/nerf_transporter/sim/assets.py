"""Procedural assets: URDFs built from boxes, cylinders and meshes, written to a cache directory.

Every file is named after a hash of its content, so the same asset is written once and differently
parametrised assets never collide. Writes are atomic (temp file, then rename). Set the environment
variable ``NERF_TRANSPORTER_CACHE`` to move the cache (default ``~/.cache/nerf_transporter/assets``).

Typical use in a task::

    parts = [Box((0.1, 0.04, 0.04), position=(0, -0.03, 0)), Box((0.04, 0.06, 0.04), (-0.03, 0.02, 0))]
    path = write_urdf("l_block", parts, color=COLORS["red"], mass=0.1)
    body = load(client, path, pose)
"""

from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nerf_transporter.atomic import write_text
from nerf_transporter.geometry import Pose

# the anchor's contact parameters of every asset; PyBullet's own default lateral friction
ROLLING_FRICTION = 1e-4
INERTIA_SCALING = 3.0
DEFAULT_FRICTION = 0.5

RGBA = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]

COLORS: dict[str, RGBA] = {
    "red": (0.839, 0.153, 0.157, 1.0),
    "green": (0.173, 0.627, 0.173, 1.0),
    "blue": (0.122, 0.467, 0.706, 1.0),
    "yellow": (0.929, 0.788, 0.282, 1.0),
    "orange": (1.000, 0.498, 0.055, 1.0),
    "purple": (0.580, 0.404, 0.741, 1.0),
    "pink": (0.890, 0.467, 0.761, 1.0),
    "cyan": (0.090, 0.745, 0.812, 1.0),
    "brown": (0.549, 0.337, 0.294, 1.0),
    "dark_brown": (0.330, 0.200, 0.176, 1.0),
    "white": (0.950, 0.950, 0.950, 1.0),
    "gray": (0.500, 0.500, 0.500, 1.0),
    "dark_gray": (0.250, 0.250, 0.250, 1.0),
    "table": (0.820, 0.780, 0.720, 1.0),
}


@dataclass(frozen=True)
class Box:
    """A box of full `size` (x, y, z), centred at `position`, rotated by `rpy` (URDF roll-pitch-yaw)."""

    size: Vec3
    position: Vec3 = (0.0, 0.0, 0.0)
    rpy: Vec3 = (0.0, 0.0, 0.0)
    color: RGBA | None = None

    @property
    def volume(self) -> float:
        return float(np.prod(self.size))


@dataclass(frozen=True)
class Cylinder:
    """A cylinder along its local z axis, centred at `position`, rotated by `rpy`."""

    radius: float
    length: float
    position: Vec3 = (0.0, 0.0, 0.0)
    rpy: Vec3 = (0.0, 0.0, 0.0)
    color: RGBA | None = None

    @property
    def volume(self) -> float:
        return math.pi * self.radius**2 * self.length


@dataclass(frozen=True)
class Mesh:
    """An OBJ mesh file (see `write_obj`) placed at `position`, rotated by `rpy`."""

    path: str
    position: Vec3 = (0.0, 0.0, 0.0)
    rpy: Vec3 = (0.0, 0.0, 0.0)
    scale: Vec3 = (1.0, 1.0, 1.0)
    color: RGBA | None = None
    volume: float = 0.0


Part = Box | Cylinder | Mesh


def box_from_bounds(
    x: tuple[float, float],
    y: tuple[float, float],
    z: tuple[float, float],
    color: RGBA | None = None,
) -> Box:
    """An axis-aligned box spanning [x0, x1] x [y0, y1] x [z0, z1]."""
    size = (x[1] - x[0], y[1] - y[0], z[1] - z[0])
    if min(size) <= 0:
        raise ValueError(f"empty box bounds {x}, {y}, {z}")
    centre = ((x[0] + x[1]) / 2, (y[0] + y[1]) / 2, (z[0] + z[1]) / 2)
    return Box(size, centre, color=color)


def cache_dir() -> Path:
    """The asset cache directory (created on demand)."""
    root = os.environ.get("NERF_TRANSPORTER_CACHE")
    path = Path(root) if root else Path.home() / ".cache" / "nerf_transporter" / "assets"
    path.mkdir(parents=True, exist_ok=True)
    return path


def cached_file(name: str, suffix: str, text: str) -> Path:
    """Path of `text` stored in the cache as `<name>-<hash><suffix>`, written if absent."""
    digest = hashlib.sha1(text.encode()).hexdigest()[:16]
    path = cache_dir() / f"{name}-{digest}{suffix}"
    if not path.exists():
        write_text(path, text)
    return path


def write_obj(name: str, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """Store a triangle mesh (vertices [N, 3] in metres, faces [M, 3] 0-based, counter-clockwise
    seen from outside) as an OBJ file in the cache and return its path."""
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=int)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError("write_obj expects vertices [N, 3] and triangle faces [M, 3]")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError("write_obj: a face refers to a vertex that does not exist")
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return cached_file(name, ".obj", "\n".join(lines) + "\n")


def _origin_xml(position: Sequence[float], rpy: Sequence[float]) -> str:
    xyz = " ".join(f"{v:.6f}" for v in position)
    angles = " ".join(f"{v:.6f}" for v in rpy)
    return f'<origin xyz="{xyz}" rpy="{angles}"/>'


def _geometry_xml(part: Part) -> str:
    if isinstance(part, Box):
        return '<box size="{:.6f} {:.6f} {:.6f}"/>'.format(*part.size)
    if isinstance(part, Cylinder):
        return f'<cylinder radius="{part.radius:.6f}" length="{part.length:.6f}"/>'
    scale = " ".join(f"{v:.6f}" for v in part.scale)
    return f'<mesh filename="{part.path}" scale="{scale}"/>'


def visual_xml(part: Part, color: RGBA) -> str:
    rgba = " ".join(f"{v:.4f}" for v in (part.color or color))
    return (
        f"<visual>{_origin_xml(part.position, part.rpy)}<geometry>{_geometry_xml(part)}</geometry>"
        f'<material name="c{rgba.replace(" ", "_")}"><color rgba="{rgba}"/></material></visual>'
    )


def collision_xml(part: Part) -> str:
    return (
        f"<collision>{_origin_xml(part.position, part.rpy)}"
        f"<geometry>{_geometry_xml(part)}</geometry></collision>"
    )


def inertial_xml(mass: float, center_of_mass: Sequence[float], inertia: float = 1e-4) -> str:
    """Inertial block; PyBullet recomputes the inertia tensor from the collision shapes."""
    return (
        f'<inertial>{_origin_xml(center_of_mass, (0, 0, 0))}<mass value="{mass:.6f}"/>'
        f'<inertia ixx="{inertia}" ixy="0" ixz="0" iyy="{inertia}" iyz="0" izz="{inertia}"/>'
        "</inertial>"
    )


def contact_xml(friction: float) -> str:
    """Contact block of every asset: its lateral friction, and the anchor's rolling friction and
    inertia scaling (docs/conventions.md, "Physics")."""
    return (
        f'<contact><lateral_friction value="{friction:.6f}"/>'
        f'<rolling_friction value="{ROLLING_FRICTION}"/>'
        f'<inertia_scaling value="{INERTIA_SCALING}"/></contact>'
    )


def center_of_mass(parts: Sequence[Part]) -> np.ndarray:
    """Volume-weighted centroid of the parts that know their volume (origin if none do)."""
    weights = np.array([part.volume for part in parts], dtype=float)
    if weights.sum() <= 0:
        return np.zeros(3)
    positions = np.array([part.position for part in parts], dtype=float)
    return (weights[:, None] * positions).sum(axis=0) / weights.sum()


def write_urdf(
    name: str,
    parts: Sequence[Part],
    color: RGBA = COLORS["gray"],
    mass: float = 0.1,
    collision_parts: Sequence[Part] | None = None,
    com: Sequence[float] | None = None,
    friction: float = DEFAULT_FRICTION,
) -> Path:
    """A single-link URDF made of `parts` (visual and, unless `collision_parts` is given, collision),
    with lateral `friction` and the centre of mass at `com` (default: the collision parts' centroid).

    Several collision parts form one compound rigid body, which is how concave objects are built
    from convex pieces. `mass` 0 with `load(..., fixed=True)` gives a static body.
    """
    if not parts:
        raise ValueError(f"asset {name!r} has no parts")
    collisions = parts if collision_parts is None else collision_parts
    center = center_of_mass(collisions) if com is None else np.asarray(com, dtype=float)
    # one element per line: PyBullet's URDF parser fails on lines of more than a few thousand characters
    body = "".join(f"\n{visual_xml(part, color)}" for part in parts)
    body += "".join(f"\n{collision_xml(part)}" for part in collisions)
    text = (
        f'<?xml version="1.0"?>\n<robot name="{name}"><link name="base">'
        f"{contact_xml(friction)}{inertial_xml(mass, center)}{body}</link></robot>\n"
    )
    return cached_file(name, ".urdf", text)


def load(client, path: Path | str, pose: Pose, fixed: bool = False) -> int:
    """Load a URDF into a `BulletClient` at `pose`; returns the body id."""
    position, quat = pose
    return client.loadURDF(
        str(path),
        basePosition=[float(v) for v in position],
        baseOrientation=[float(v) for v in quat],
        useFixedBase=fixed,
    )


def get_pose(client, body: int) -> Pose:
    """Pose of a body's URDF link frame (PyBullet reports the centre-of-mass frame)."""
    com_position, com_quat = client.getBasePositionAndOrientation(body)
    local_position, local_quat = client.getDynamicsInfo(body, -1)[3:5]
    position, quat = client.multiplyTransforms(
        com_position, com_quat, *client.invertTransform(local_position, local_quat)
    )
    return np.array(position), np.array(quat)


def set_pose(client, body: int, pose: Pose) -> None:
    """Teleport a body so that its URDF link frame is at `pose` (velocities zeroed)."""
    local_position, local_quat = client.getDynamicsInfo(body, -1)[3:5]
    position, quat = client.multiplyTransforms(
        [float(v) for v in pose[0]], [float(v) for v in pose[1]], local_position, local_quat
    )
    client.resetBasePositionAndOrientation(body, position, quat)
    client.resetBaseVelocity(body, (0, 0, 0), (0, 0, 0))
