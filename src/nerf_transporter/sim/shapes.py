"""Procedural solids of the bowl, hanging-disk and stacking-kit tasks, as lists of convex pieces.

PyBullet collides a body made of several convex collision shapes as a compound, which is how the
concave solids here (bowls, a disk with a hole, star- and letter-shaped kit objects) stay robust
in contact. Each piece is an (K, 3) array of points whose convex hull is
the piece; `hull_mesh` turns it into a closed triangle mesh.

Every kit shape is a polygon that is star-shaped about its own origin (every edge seen
counter-clockwise from the origin), so that the fan from the origin cuts it into convex pieces.
The train/test split of the shapes is fixed here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from nerf_transporter import geometry
from nerf_transporter.sim.assets import RGBA, Box, Cylinder, Mesh, Part, write_obj, write_urdf

# ---------------------------------------------------------------------------------------------
# Dimensions (metres)
# ---------------------------------------------------------------------------------------------

CUBE_SIZE = 0.04  # edge of place-red-in-green's red block (the anchor's stacking/block.urdf)

# place-red-in-green's bowl: the anchor's bowl/bowl.urdf collides as a cup mesh scaled (1, 1, 0.4),
# a convex decomposition (the figures below are read from that mesh, as PyBullet's Cup/cup_vhacd.obj
# holds it): a solid foot, then a straight wall around a cylindrical cavity
BOWL_RIM_RADIUS = 0.047  # outer radius of the wall: the mesh is 9.2 cm across in x, 9.4 cm in y
BOWL_INNER_RADIUS = 0.031  # the cavity's radius: the mesh's inner wall faces lie 2.6-3.5 cm out
BOWL_FOOT_RADIUS = 0.037  # the foot under the cavity floor: the mesh's base is about 7.4 cm across
BOWL_FLOOR_HEIGHT = 0.0145  # top of the cavity floor above the underside: the mesh's 1.1-1.6 cm
BOWL_HEIGHT = 0.056  # the rim above the underside: the mesh is 0.14 tall, scaled 0.4 in z
# the bowl's axis in its body frame: the mesh is centred 2.15 cm off its origin, whose plane is its
# underside (the mesh spans x -0.066..0.026, y -0.040..0.054, z -0.0003..0.056 after scaling)
BOWL_AXIS = (-0.0203, 0.0071)
BOWL_SEGMENTS = 16  # sides of the foot's and wall's polygons (ours; the mesh: 10 wall pieces)
BOWL_MASS = 0.1  # kg, the anchor's (the distractor bowls move; a fixed body ignores it)
BOWL_FRICTION = 1.0  # lateral, the anchor's
BOWL_CENTER_OF_MASS = (-0.01, 0.0, 0.02)  # the anchor's inertial origin in the body frame

# hanging-disks (the anchor's hanging_disks/disk.urdf and stand.urdf)
DISK_RADIUS = 0.045  # outer radius: the anchor's ring mesh scaled 0.0015 in x and y
DISK_HOLE_RADIUS = 0.0225  # the anchor's hole, same scale
DISK_THICKNESS = 0.01  # the anchor's mesh scaled 0.001 in z; origin at mid-thickness (our choice)
DISK_SEGMENTS = 16  # sides of the ring's polygons, vertices on both radii (ours: no figure)
DISK_MASS = 0.1  # kg, the anchor's
DISK_FRICTION = 1.0  # lateral, the anchor's
STAND_PLATE_SIZE = (0.1, 0.1, 0.01)  # the anchor's collision box, centred on the stand's origin
STAND_BOX_SIZE = (0.05, 0.05, 0.01)  # the anchor's visual box in the plate's place (all one sees)
ROD_RADIUS = 0.005  # the anchor's cylinder
ROD_LENGTH = 0.1  # the anchor's cylinder
ROD_CENTRE_HEIGHT = 0.03  # the anchor's cylinder origin above the stand's; also its target offset
STAND_MASS = 0.1  # kg, the anchor's (a fixed body: PyBullet ignores it)
STAND_FRICTION = 0.5  # lateral, the anchor's

KIT_OBJECT_SIZE = 0.057  # longer side of a kit object's bounding box: the anchor's meshes span
#   18.9-20 mesh units x scale 0.003 (ravens kitting/00.obj, 05.obj, 14.obj)
KIT_OBJECT_THICKNESS = 0.02  # the anchor's meshes: z 0-20 units x scale 0.001, origin at the bottom
KIT_OBJECT_MASS = 0.1  # the anchor's kitting/object-template.urdf
KIT_OBJECT_FRICTION = 2.0  # lateral; the anchor's object-template.urdf (its copy on the kit too)
KIT_TARGET_COLOR = (0.2, 0.2, 0.2, 1.0)  # the anchor's dark copy of the object on the kit
KIT_PLATE_SIZE = (0.1, 0.1, 0.005)  # the anchor's kitting/kit_sixdof.urdf box
KIT_PLATE_COLOR = (0.612, 0.459, 0.373, 1.0)  # kit_sixdof.urdf's rgba
KIT_PLATE_FRICTION = 1.0  # lateral; kit_sixdof.urdf

# ---------------------------------------------------------------------------------------------
# 2-D polygons (counter-clockwise (N, 2) arrays)
# ---------------------------------------------------------------------------------------------


def _cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def polygon_area(outline: np.ndarray) -> float:
    """Signed area (positive for counter-clockwise outlines)."""
    outline = np.asarray(outline, dtype=float)
    return 0.5 * float(_cross2(outline, np.roll(outline, -1, axis=0)).sum())


def polygon_centroid(outline: np.ndarray) -> np.ndarray:
    outline = np.asarray(outline, dtype=float)
    nxt = np.roll(outline, -1, axis=0)
    cross = _cross2(outline, nxt)
    return ((outline + nxt) * cross[:, None]).sum(axis=0) / (3.0 * cross.sum())


def is_star_shaped(outline: np.ndarray, eps: float = 1e-9) -> bool:
    """Whether every edge is seen counter-clockwise from the origin (the fan from it is valid)."""
    outline = np.asarray(outline, dtype=float)
    return bool(np.all(_cross2(outline, np.roll(outline, -1, axis=0)) > eps))


def is_convex(outline: np.ndarray, eps: float = 1e-12) -> bool:
    outline = np.asarray(outline, dtype=float)
    edges = np.roll(outline, -1, axis=0) - outline
    return bool(np.all(_cross2(edges, np.roll(edges, -1, axis=0)) >= -eps))


def symmetry_order(outline: np.ndarray, max_order: int = 64, tol: float = 1e-6) -> int:
    """Largest k such that rotating the outline by 2 pi / k about the origin maps it onto itself."""
    outline = np.asarray(outline, dtype=float)
    best = 1
    for order in range(2, max_order + 1):
        angle = 2 * math.pi / order
        rotation = np.array(
            [[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]]
        )
        rotated = geometry.matmul(outline, rotation.T)
        distances = np.linalg.norm(rotated[:, None, :] - outline[None, :, :], axis=-1)
        if np.all(distances.min(axis=1) < tol):
            best = order
    return best


def fan_pieces(outline: np.ndarray) -> list[np.ndarray]:
    """Convex pieces of a star-shaped polygon: fan triangles from the origin, greedily merged."""
    outline = np.asarray(outline, dtype=float)
    if is_convex(outline):
        return [outline]
    edges = np.roll(outline, -1, axis=0) - outline
    reflex = np.flatnonzero(_cross2(np.roll(edges, 1, axis=0), edges) < 0)
    start = int(reflex[0])
    order = [(start + k) % len(outline) for k in range(len(outline) + 1)]
    origin = np.zeros(2)
    pieces, current = [], [order[0], order[1]]
    for index in order[2:]:
        candidate = [*current, index]
        if is_convex(np.vstack([origin, outline[candidate]])):
            current = candidate
        else:
            pieces.append(np.vstack([origin, outline[current]]))
            current = [current[-1], index]
    pieces.append(np.vstack([origin, outline[current]]))
    return pieces


def regular_polygon(sides: int, radius: float, phase: float = 0.0) -> np.ndarray:
    angles = phase + 2 * math.pi * np.arange(sides) / sides
    return radius * geometry.cos_sin(angles)


def star_polygon(points: int, outer: float, inner: float) -> np.ndarray:
    angles = math.pi / 2 + math.pi * np.arange(2 * points) / points
    radii = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return radii[:, None] * geometry.cos_sin(angles)


def arms_polygon(angles_deg: list[float], lengths: list[float], half_width: float) -> np.ndarray:
    """Union of straight arms of equal width leaving the origin (plus, X, Y, T, L, V, cross)."""
    angles = np.radians(angles_deg)
    directions = geometry.cos_sin(angles)
    left = np.stack([-directions[:, 1], directions[:, 0]], axis=1)
    vertices = []
    for k in range(len(angles)):
        tip = lengths[k] * directions[k]
        vertices += [tip - half_width * left[k], tip + half_width * left[k]]
        nxt = (k + 1) % len(angles)
        # corner between the left side of arm k and the right side of the next arm
        matrix = np.stack([left[k], left[nxt]])
        determinant = matrix[0, 0] * matrix[1, 1] - matrix[0, 1] * matrix[1, 0]
        if abs(determinant) < 1e-9:
            vertices.append(half_width * left[k])
        else:  # Cramer's rule for matrix @ corner = (half_width, -half_width)
            corner_x = half_width * matrix[1, 1] + half_width * matrix[0, 1]
            corner_y = -half_width * matrix[0, 0] - half_width * matrix[1, 0]
            vertices.append(np.array([corner_x, corner_y]) / determinant)
    return np.array(vertices)


def _centred(outline: np.ndarray, origin: tuple[float, float]) -> np.ndarray:
    return np.asarray(outline, dtype=float) - np.asarray(origin, dtype=float)


# ---------------------------------------------------------------------------------------------
# Kit shapes: catalogue and fixed train/test split
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class KitShape:
    """An extruded kit object: a star-shaped outline (metres) and its rotational symmetry order."""

    name: str
    outline: np.ndarray
    symmetry: int

    @property
    def yaw_period(self) -> float:
        return 2 * math.pi / self.symmetry


def _heart(samples: int = 16) -> np.ndarray:
    t = np.linspace(0.0, 2 * math.pi, samples, endpoint=False)
    t = np.delete(t, [1, samples - 1])  # a wide notch at the top
    sin = geometry.cos_sin(t)[:, 1]
    cos_t, cos_2t, cos_3t, cos_4t = (geometry.cos_sin(k * t)[:, 0] for k in (1, 2, 3, 4))
    x = 16 * sin * sin * sin
    y = 13 * cos_t - 5 * cos_2t - 2 * cos_3t - cos_4t
    return _centred(np.stack([x, y], axis=1) * (4.3 / 17.0), (0.0, -0.2))


def _semicircle(radius: float = 4.4, samples: int = 16) -> np.ndarray:
    angles = np.linspace(0.0, math.pi, samples)
    outline = radius * geometry.cos_sin(angles)
    return _centred(outline, (0.0, 4 * radius / (3 * math.pi)))


def _shape_outlines_cm() -> dict[str, np.ndarray]:
    """Every kit outline about its own origin, in centimetres (`_build_kit_shapes` scales it)."""
    return {
        "triangle": regular_polygon(3, 4.4, math.pi / 2),
        "square": regular_polygon(4, 4.1, math.pi / 4),
        "pentagon": regular_polygon(5, 4.0, math.pi / 2),
        "hexagon": regular_polygon(6, 3.9),
        "heptagon": regular_polygon(7, 3.9, math.pi / 2),
        "octagon": regular_polygon(8, 3.9, math.pi / 8),
        "circle": regular_polygon(32, 3.7),
        "rectangle": np.array([[-4.2, -2.2], [4.2, -2.2], [4.2, 2.2], [-4.2, 2.2]]),
        "rhombus": np.array([[-4.4, 0.0], [0.0, -2.7], [4.4, 0.0], [0.0, 2.7]]),
        "parallelogram": np.array([[-4.4, -2.2], [2.4, -2.2], [4.4, 2.2], [-2.4, 2.2]]),
        "trapezoid": _centred([[-4.4, -2.4], [4.4, -2.4], [2.2, 2.6], [-2.2, 2.6]], (0.0, -0.3)),
        "right-triangle": _centred([[-2.8, -2.6], [4.6, -2.6], [-2.8, 3.6]], (-0.3, -0.5)),
        "kite": _centred([[0.0, -4.6], [2.8, 0.8], [0.0, 3.0], [-2.8, 0.8]], (0.0, 0.0)),
        "house": _centred([[-3.2, -3.4], [3.2, -3.4], [3.2, 0.8], [0.0, 4.2], [-3.2, 0.8]], (0, 0)),
        "star-4": star_polygon(4, 4.6, 1.9),
        "star-5": star_polygon(5, 4.6, 2.1),
        "star-6": star_polygon(6, 4.6, 2.4),
        "star-8": star_polygon(8, 4.5, 2.8),
        "plus": arms_polygon([0, 90, 180, 270], [4.2, 4.2, 4.2, 4.2], 1.3),
        "cross": _centred(arms_polygon([0, 90, 180, 270], [2.6, 2.4, 2.6, 4.8], 1.2), (0, -0.6)),
        "letter-x": arms_polygon([30, 150, 210, 330], [4.6, 4.6, 4.6, 4.6], 1.1),
        "letter-y": arms_polygon([55, 125, 270], [4.3, 4.3, 4.2], 1.1),
        "letter-t": _centred(arms_polygon([0, 180, 270], [3.6, 3.6, 4.2], 1.2), (0, -0.6)),
        "letter-l": _centred(arms_polygon([0, 90], [3.4, 5.0], 1.2), (0.4, 0.6)),
        "letter-v": _centred(arms_polygon([65, 115], [5.4, 5.4], 1.1), (0.0, 1.6)),
        "arrow": _centred(
            [
                [-4.0, -0.9],
                [1.0, -0.9],
                [1.0, -2.6],
                [4.6, 0.0],
                [1.0, 2.6],
                [1.0, 0.9],
                [-4.0, 0.9],
            ],
            (1.4, 0.0),
        ),
        "heart": _heart(),
        "semicircle": _semicircle(),
        "hourglass": np.array(
            [[-3.0, -3.8], [3.0, -3.8], [0.9, 0.0], [3.0, 3.8], [-3.0, 3.8], [-0.9, 0.0]]
        ),
    }


TEST_KIT_SHAPES = (
    "heptagon",
    "parallelogram",
    "kite",
    "house",
    "star-6",
    "letter-t",
    "letter-x",
    "cross",
)


def _build_kit_shapes() -> dict[str, KitShape]:
    """Every outline scaled, about its origin, so that its bounding box's longer side is
    `KIT_OBJECT_SIZE` (as the anchor's meshes are)."""
    shapes = {}
    for name, outline_cm in _shape_outlines_cm().items():
        outline = np.asarray(outline_cm, dtype=float)
        outline = outline * (KIT_OBJECT_SIZE / np.ptp(outline, axis=0).max())
        if polygon_area(outline) < 0:
            outline = outline[::-1]
        shapes[name] = KitShape(name, outline, symmetry_order(outline))
    return shapes


KIT_SHAPES: dict[str, KitShape] = _build_kit_shapes()
TRAIN_KIT_SHAPES = tuple(name for name in KIT_SHAPES if name not in TEST_KIT_SHAPES)


def kit_shapes_for_split(split: str) -> tuple[str, ...]:
    """Shapes of a seed split: test seeds use unseen shapes; train and validation the others."""
    return TEST_KIT_SHAPES if split == "test" else TRAIN_KIT_SHAPES


# ---------------------------------------------------------------------------------------------
# 3-D pieces and meshes
# ---------------------------------------------------------------------------------------------


def prism(polygon: np.ndarray, z_low: float, z_high: float) -> np.ndarray:
    """Points of a vertical prism over a convex 2-D polygon."""
    polygon = np.asarray(polygon, dtype=float)
    low = np.column_stack([polygon, np.full(len(polygon), z_low)])
    high = np.column_stack([polygon, np.full(len(polygon), z_high)])
    return np.vstack([low, high])


def hull_mesh(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed triangle mesh (vertices, faces with outward normals) of the convex hull of points."""
    hull = ConvexHull(np.asarray(points, dtype=float))
    used = np.unique(hull.simplices)
    remap = -np.ones(len(hull.points), dtype=int)
    remap[used] = np.arange(len(used))
    vertices = hull.points[used]
    faces = remap[hull.simplices]
    centre = vertices.mean(axis=0)
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    outward = (np.cross(b - a, c - a) * (a - centre)).sum(axis=1) > 0
    faces[~outward] = faces[~outward][:, ::-1]
    return vertices, faces


def _sector(radius: float, angle: float) -> np.ndarray:
    return np.array([radius * math.cos(angle), radius * math.sin(angle)])


def ring_pieces(
    inner: float, outer: float, z_low: float, z_high: float, segments: int
) -> list[np.ndarray]:
    """A flat annulus cut into `segments` convex blocks (polygonal inner and outer circles)."""
    angles = 2 * math.pi * np.arange(segments + 1) / segments
    return [
        prism(
            [_sector(inner, a0), _sector(outer, a0), _sector(outer, a1), _sector(inner, a1)],
            z_low,
            z_high,
        )
        for a0, a1 in zip(angles[:-1], angles[1:], strict=True)
    ]


def disc_piece(radius: float, z_low: float, z_high: float, segments: int = 24) -> np.ndarray:
    return prism(regular_polygon(segments, radius), z_low, z_high)


def bowl_pieces() -> list[np.ndarray]:
    """Bowl with its origin in the plane of its underside, `BOWL_AXIS` off its axis: a solid foot
    whose top is the cavity floor, and a straight wall around the cavity in `BOWL_SEGMENTS` blocks."""
    foot = prism(regular_polygon(BOWL_SEGMENTS, BOWL_FOOT_RADIUS), 0.0, BOWL_FLOOR_HEIGHT)
    inner, outer = (regular_polygon(BOWL_SEGMENTS, r) for r in (BOWL_INNER_RADIUS, BOWL_RIM_RADIUS))
    wall = [
        prism([inner[k], outer[k], outer[k - 1], inner[k - 1]], BOWL_FLOOR_HEIGHT, BOWL_HEIGHT)
        for k in range(BOWL_SEGMENTS)
    ]
    axis = np.array([*BOWL_AXIS, 0.0])
    return [piece + axis for piece in [foot, *wall]]


def bowl_seat() -> np.ndarray:
    """Where, in a bowl's frame, the centre of a cube resting on the middle of its floor lies."""
    return np.array([*BOWL_AXIS, BOWL_FLOOR_HEIGHT + CUBE_SIZE / 2])


def disk_pieces() -> list[np.ndarray]:
    """Disk with a central hole, origin at its centre (mid-thickness)."""
    half = DISK_THICKNESS / 2
    return ring_pieces(DISK_HOLE_RADIUS, DISK_RADIUS, -half, half, DISK_SEGMENTS)


def stand_rod() -> Cylinder:
    """The stand's rod along its z axis, through the plate (the anchor's cylinder)."""
    return Cylinder(ROD_RADIUS, ROD_LENGTH, position=(0.0, 0.0, ROD_CENTRE_HEIGHT))


def stand_parts() -> tuple[list[Part], list[Part]]:
    """(visual, collision) parts of the stand, origin at the centre of its plate: the anchor's
    stand shows a 5 cm box where it collides as a 10 cm plate, and a rod sticking up from both."""
    visual = [Box(STAND_BOX_SIZE), stand_rod()]
    collision = [Box(STAND_PLATE_SIZE), stand_rod()]
    return visual, collision


def rod_tip_height() -> float:
    """Height of the rod's tip above the stand's origin."""
    return ROD_CENTRE_HEIGHT + ROD_LENGTH / 2


def disk_rest_height() -> float:
    """Height above the stand's origin of the centre of a disk lying on the plate."""
    return STAND_PLATE_SIZE[2] / 2 + DISK_THICKNESS / 2


def kit_object_pieces(shape: KitShape) -> list[np.ndarray]:
    """Extruded kit object, origin at the outline's origin on its bottom face (the anchor's)."""
    return [prism(piece, 0.0, KIT_OBJECT_THICKNESS) for piece in fan_pieces(shape.outline)]


# ---------------------------------------------------------------------------------------------
# URDF assets (written once to the asset cache)
# ---------------------------------------------------------------------------------------------


def mesh_parts(name: str, pieces: list[np.ndarray]) -> list[Mesh]:
    """One cached OBJ per convex piece, as URDF mesh parts (the collision shapes of a compound)."""
    return [
        Mesh(str(write_obj(f"{name}-{index}", *hull_mesh(piece))))
        for index, piece in enumerate(pieces)
    ]


def merged_mesh(name: str, pieces: list[np.ndarray], color: RGBA | None = None) -> Mesh:
    """All pieces in one cached OBJ: a single visual shape renders faster than many."""
    vertices, faces, count = [], [], 0
    for piece in pieces:
        piece_vertices, piece_faces = hull_mesh(piece)
        vertices.append(piece_vertices)
        faces.append(piece_faces + count)
        count += len(piece_vertices)
    return Mesh(str(write_obj(name, np.vstack(vertices), np.vstack(faces))), color=color)


def write_solid(
    name: str,
    pieces: list[np.ndarray],
    color: RGBA,
    mass: float,
    friction: float,
    com: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> str:
    """URDF of a compound of convex pieces (drawn as one merged mesh) with its centre of mass at
    `com` (default the body origin, as the anchor's URDFs put it)."""
    visual = [merged_mesh(f"{name}-visual", pieces)]
    collision = mesh_parts(name, pieces)
    path = write_urdf(
        name, visual, color, mass, collision_parts=collision, com=com, friction=friction
    )
    return str(path)


def bowl_urdf(color: RGBA) -> str:
    """The anchor's bowl: mass, friction and centre of mass its URDF's (the green ones are fixed)."""
    return write_solid("bowl", bowl_pieces(), color, BOWL_MASS, BOWL_FRICTION, BOWL_CENTER_OF_MASS)


def disk_urdf(color: RGBA) -> str:
    """The disk: a compound of convex ring blocks, so that its hole is a real hole."""
    return write_solid("disk", disk_pieces(), color, DISK_MASS, DISK_FRICTION)


def stand_urdf(color: RGBA) -> str:
    """The stand (load it fixed)."""
    visual, collision = stand_parts()
    path = write_urdf(
        "stand",
        visual,
        color,
        STAND_MASS,
        collision_parts=collision,
        com=(0, 0, 0),
        friction=STAND_FRICTION,
    )
    return str(path)


def kit_object_urdf(shape: KitShape, color: RGBA) -> str:
    """A kit object with the anchor's mass and friction: movable, or loaded fixed as its copy."""
    pieces = kit_object_pieces(shape)
    return write_solid(f"kit-{shape.name}", pieces, color, KIT_OBJECT_MASS, KIT_OBJECT_FRICTION)


def kit_plate_urdf() -> str:
    """The kit: a thin box with its origin at its centre (the anchor's kit_sixdof.urdf)."""
    plate = [Box(KIT_PLATE_SIZE)]
    path = write_urdf(
        "kit-plate", plate, KIT_PLATE_COLOR, 0.0, com=(0, 0, 0), friction=KIT_PLATE_FRICTION
    )
    return str(path)
