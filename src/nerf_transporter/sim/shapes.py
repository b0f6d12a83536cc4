"""Procedural solids of the bowl, hanging-disk and stacking-kit tasks, as lists of convex pieces.

PyBullet collides a body made of several convex collision shapes as a compound, which is how the
concave solids here (bowls, a disk with a hole, a kit plate with a cavity, star- and letter-shaped
kit objects) stay robust in contact. Each piece is an (K, 3) array of points whose convex hull is
the piece; `hull_mesh` turns it into a closed triangle mesh.

Every kit shape is a polygon that is star-shaped about its own origin (every edge seen
counter-clockwise from the origin), so that the fan from the origin cuts both the shape and the
plate around its cavity into convex pieces. The train/test split of the shapes is fixed here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from nerf_transporter.sim.assets import RGBA, Mesh, write_obj, write_urdf

# ---------------------------------------------------------------------------------------------
# Dimensions (metres)
# ---------------------------------------------------------------------------------------------

CUBE_SIZE = 0.04

BOWL_FLOOR_RADIUS = 0.04
BOWL_RIM_RADIUS = 0.062
BOWL_HEIGHT = 0.05
BOWL_THICKNESS = 0.006
BOWL_SEGMENTS = 16

DISK_RADIUS = 0.04
DISK_HOLE_RADIUS = 0.013
DISK_THICKNESS = 0.012
DISK_SEGMENTS = 16
STAND_RADIUS = 0.056
STAND_THICKNESS = 0.01
ROD_RADIUS = 0.006
ROD_LENGTH = 0.032

KIT_THICKNESS = 0.016
KIT_CAVITY_DEPTH = 0.01
KIT_FLOOR_THICKNESS = 0.006
KIT_CLEARANCE = 0.004
KIT_BORDER = 0.018

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
        rotated = outline @ rotation.T
        distances = np.linalg.norm(rotated[:, None, :] - outline[None, :, :], axis=-1)
        if np.all(distances.min(axis=1) < tol):
            best = order
    return best


def offset_polygon(outline: np.ndarray, distance: float) -> np.ndarray:
    """Grow a counter-clockwise polygon by `distance` (mitred corners: every edge moves out)."""
    outline = np.asarray(outline, dtype=float)
    edges = np.roll(outline, -1, axis=0) - outline
    normals = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    before = np.roll(normals, 1, axis=0)  # normal of the edge ending at each vertex
    miter = (before + normals) / (1.0 + (before * normals).sum(axis=1, keepdims=True))
    return outline + distance * miter


def clip_to_square(polygon: np.ndarray, half_size: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex polygon to the square [-h, h]^2."""
    result = [np.asarray(p, dtype=float) for p in polygon]
    for axis in (0, 1):
        for sign in (1.0, -1.0):
            inside = [sign * p[axis] <= half_size for p in result]
            clipped = []
            for index, point in enumerate(result):
                nxt = result[(index + 1) % len(result)]
                nxt_inside = inside[(index + 1) % len(result)]
                if inside[index]:
                    clipped.append(point)
                if inside[index] != nxt_inside:
                    t = (sign * half_size - point[axis]) / (nxt[axis] - point[axis])
                    clipped.append(point + t * (nxt - point))
            result = clipped
    return np.array(result)


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


def frame_pieces(outline: np.ndarray, half_size: float) -> list[np.ndarray]:
    """Convex pieces covering the square [-h, h]^2 minus a star-shaped polygon inside it."""
    outline = np.asarray(outline, dtype=float)
    far = 4.0 * half_size / np.linalg.norm(outline, axis=1).min()
    pieces = []
    for a, b in zip(outline, np.roll(outline, -1, axis=0), strict=True):
        piece = clip_to_square(np.array([a, a * far, b * far, b]), half_size)
        if len(piece) >= 3 and polygon_area(piece) > 1e-8:
            pieces.append(piece)
    return pieces


def regular_polygon(sides: int, radius: float, phase: float = 0.0) -> np.ndarray:
    angles = phase + 2 * math.pi * np.arange(sides) / sides
    return radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def star_polygon(points: int, outer: float, inner: float) -> np.ndarray:
    angles = math.pi / 2 + math.pi * np.arange(2 * points) / points
    radii = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return radii[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def arms_polygon(angles_deg: list[float], lengths: list[float], half_width: float) -> np.ndarray:
    """Union of straight arms of equal width leaving the origin (plus, X, Y, T, L, V, cross)."""
    angles = np.radians(angles_deg)
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    left = np.stack([-directions[:, 1], directions[:, 0]], axis=1)
    vertices = []
    for k in range(len(angles)):
        tip = lengths[k] * directions[k]
        vertices += [tip - half_width * left[k], tip + half_width * left[k]]
        nxt = (k + 1) % len(angles)
        # corner between the left side of arm k and the right side of the next arm
        matrix = np.stack([left[k], left[nxt]])
        if abs(np.linalg.det(matrix)) < 1e-9:
            vertices.append(half_width * left[k])
        else:
            vertices.append(np.linalg.solve(matrix, [half_width, -half_width]))
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
    t = np.delete(t, [1, samples - 1])  # keep the notch at the top wide enough for a cavity
    x = 16 * np.sin(t) ** 3
    y = 13 * np.cos(t) - 5 * np.cos(2 * t) - 2 * np.cos(3 * t) - np.cos(4 * t)
    return _centred(np.stack([x, y], axis=1) * (4.3 / 17.0), (0.0, -0.2))


def _semicircle(radius: float = 4.4, samples: int = 16) -> np.ndarray:
    angles = np.linspace(0.0, math.pi, samples)
    outline = radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return _centred(outline, (0.0, 4 * radius / (3 * math.pi)))


def _shape_outlines_cm() -> dict[str, np.ndarray]:
    """Every kit outline in centimetres, about its own origin."""
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
    shapes = {}
    for name, outline_cm in _shape_outlines_cm().items():
        outline = np.asarray(outline_cm, dtype=float) * 0.01
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
    outward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a - centre) > 0
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
    """Bowl with its origin at the centre of the underside: a floor disc and a flared wall."""
    slope = math.atan2(BOWL_HEIGHT - BOWL_THICKNESS, BOWL_RIM_RADIUS - BOWL_FLOOR_RADIUS)
    out = np.array([math.sin(slope), -math.cos(slope)]) * BOWL_THICKNESS  # (r, z) outward
    inner_bottom = np.array([BOWL_FLOOR_RADIUS, BOWL_THICKNESS])
    inner_top = np.array([BOWL_RIM_RADIUS, BOWL_HEIGHT])
    profile = [inner_bottom, inner_top, inner_top + out, inner_bottom + out]
    pieces = [disc_piece(BOWL_FLOOR_RADIUS + out[0], 0.0, BOWL_THICKNESS, BOWL_SEGMENTS)]
    angles = 2 * math.pi * np.arange(BOWL_SEGMENTS + 1) / BOWL_SEGMENTS
    for a0, a1 in zip(angles[:-1], angles[1:], strict=True):
        points = [[r * math.cos(a), r * math.sin(a), z] for a in (a0, a1) for r, z in profile]
        pieces.append(np.array(points))
    return pieces


def bowl_rest_height() -> float:
    """Height above a bowl's origin of the centre of a cube resting on its floor."""
    return BOWL_THICKNESS + CUBE_SIZE / 2


def disk_pieces() -> list[np.ndarray]:
    """Disk with a central hole, origin at its centre (mid-thickness)."""
    half = DISK_THICKNESS / 2
    return ring_pieces(DISK_HOLE_RADIUS, DISK_RADIUS, -half, half, DISK_SEGMENTS)


def stand_pieces() -> list[np.ndarray]:
    """Stand with its origin at the centre of the plate's top face: a plate and a rod along +z."""
    return [
        disc_piece(STAND_RADIUS, -STAND_THICKNESS, 0.0),
        disc_piece(ROD_RADIUS, -STAND_THICKNESS / 2, ROD_LENGTH, segments=12),
    ]


def hanging_height() -> float:
    """Height above the stand's origin of a hanging disk's centre."""
    return DISK_THICKNESS / 2


def kit_object_pieces(shape: KitShape) -> list[np.ndarray]:
    """Extruded kit object, origin at the outline's origin, mid-thickness."""
    half = KIT_THICKNESS / 2
    return [prism(piece, -half, half) for piece in fan_pieces(shape.outline)]


def kit_half_size(shape: KitShape) -> float:
    """Half side of the square kit plate that holds a shape."""
    cavity = offset_polygon(shape.outline, KIT_CLEARANCE)
    return float(np.abs(cavity).max()) + KIT_BORDER


def kit_plate_pieces(shape: KitShape) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(floor, rim) pieces of a kit plate whose origin is the centre of the cavity floor."""
    half = kit_half_size(shape)
    cavity = offset_polygon(shape.outline, KIT_CLEARANCE)
    floor = [prism(regular_polygon(4, half * math.sqrt(2), math.pi / 4), -KIT_FLOOR_THICKNESS, 0)]
    rim = [prism(piece, 0.0, KIT_CAVITY_DEPTH) for piece in frame_pieces(cavity, half)]
    return floor, rim


def kit_rest_height() -> float:
    """Height above the kit plate's origin of a seated object's centre."""
    return KIT_THICKNESS / 2


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


def write_solid(name: str, pieces: list[np.ndarray], color: RGBA, mass: float) -> str:
    """URDF of a compound of convex pieces with its centre of mass at the body origin."""
    visual = [merged_mesh(f"{name}-visual", pieces)]
    collision = mesh_parts(name, pieces)
    path = write_urdf(name, visual, color, mass, collision_parts=collision, com=(0, 0, 0))
    return str(path)


def bowl_urdf(color: RGBA) -> str:
    return write_solid("bowl", bowl_pieces(), color, mass=0.0)


def disk_urdf(color: RGBA) -> str:
    return write_solid("disk", disk_pieces(), color, mass=0.05)


def stand_urdf(color: RGBA) -> str:
    return write_solid("stand", stand_pieces(), color, mass=0.0)


def kit_object_urdf(shape: KitShape, color: RGBA) -> str:
    return write_solid(f"kit-{shape.name}", kit_object_pieces(shape), color, mass=0.05)


def kit_plate_urdf(shape: KitShape, rim_color: RGBA, floor_color: RGBA) -> str:
    """Fixed kit plate; the cavity floor has its own colour so the silhouette shows in RGB."""
    floor, rim = kit_plate_pieces(shape)
    name = f"kit-plate-{shape.name}"
    visual = [merged_mesh(f"{name}-floor", floor, floor_color), merged_mesh(f"{name}-rim", rim)]
    collision = mesh_parts(name, floor + rim)
    path = write_urdf(name, visual, rim_color, 0.0, collision_parts=collision, com=(0, 0, 0))
    return str(path)
