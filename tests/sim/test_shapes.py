import math
from collections import Counter

import numpy as np
import pytest

from nerf_transporter.sim import shapes


def _closed_outward(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Assert every directed edge has exactly one opposite edge; return the enclosed volume."""
    edges = Counter(
        (int(a), int(b)) for face in faces for a, b in zip(face, np.roll(face, -1), strict=True)
    )
    assert all(count == 1 and edges[(b, a)] == 1 for (a, b), count in edges.items())
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", np.cross(a, b), c).sum() / 6.0)


def _volume(pieces: list[np.ndarray]) -> float:
    return sum(_closed_outward(*shapes.hull_mesh(piece)) for piece in pieces)


def test_kit_catalogue_has_twenty_shapes_and_a_disjoint_fixed_split():
    assert len(shapes.KIT_SHAPES) >= 20
    train, test = set(shapes.TRAIN_KIT_SHAPES), set(shapes.TEST_KIT_SHAPES)
    assert train.isdisjoint(test) and train | test == set(shapes.KIT_SHAPES)
    assert len(test) >= 5 and len(train) >= 15
    assert shapes.kit_shapes_for_split("test") == shapes.TEST_KIT_SHAPES
    assert shapes.kit_shapes_for_split("train") == shapes.TRAIN_KIT_SHAPES
    assert shapes.kit_shapes_for_split("validation") == shapes.TRAIN_KIT_SHAPES


@pytest.mark.parametrize(
    "name,order",
    [
        ("triangle", 3),
        ("square", 4),
        ("heptagon", 7),
        ("rectangle", 2),
        ("star-5", 5),
        ("plus", 4),
        ("letter-x", 2),
        ("letter-l", 1),
        ("arrow", 1),
        ("heart", 1),
        ("hourglass", 2),
    ],
)
def test_symmetry_orders(name, order):
    assert shapes.KIT_SHAPES[name].symmetry == order
    assert math.isclose(shapes.KIT_SHAPES[name].yaw_period, 2 * math.pi / order)


@pytest.mark.parametrize("name", sorted(shapes.KIT_SHAPES))
def test_kit_shape_pieces_are_closed_and_fill_the_shape(name):
    shape = shapes.KIT_SHAPES[name]
    assert shapes.polygon_area(shape.outline) > 0
    assert shapes.is_star_shaped(shape.outline)
    volume = _volume(shapes.kit_object_pieces(shape))
    assert volume == pytest.approx(shapes.polygon_area(shape.outline) * shapes.KIT_THICKNESS)
    floor, rim = shapes.kit_plate_pieces(shape)
    side = 2 * shapes.kit_half_size(shape)
    cavity = shapes.offset_polygon(shape.outline, shapes.KIT_CLEARANCE)
    assert _volume(rim) == pytest.approx(
        (side**2 - shapes.polygon_area(cavity)) * shapes.KIT_CAVITY_DEPTH
    )
    assert _volume(floor) == pytest.approx(side**2 * shapes.KIT_FLOOR_THICKNESS)


@pytest.mark.parametrize("name", sorted(shapes.KIT_SHAPES))
def test_cavity_holds_the_shape_with_clearance(name):
    outline = shapes.KIT_SHAPES[name].outline
    cavity = shapes.offset_polygon(outline, shapes.KIT_CLEARANCE)
    assert shapes.is_star_shaped(cavity)
    # every edge moved out by exactly the clearance
    for a, b, a2 in zip(outline, np.roll(outline, -1, axis=0), cavity, strict=True):
        normal = np.array([b[1] - a[1], a[0] - b[0]]) / np.linalg.norm(b - a)
        assert np.dot(a2 - a, normal) == pytest.approx(shapes.KIT_CLEARANCE)


def test_fan_pieces_are_convex():
    for shape in shapes.KIT_SHAPES.values():
        assert all(shapes.is_convex(piece) for piece in shapes.fan_pieces(shape.outline))


def test_bowl_disk_and_stand_meshes_are_closed():
    bowl = _volume(shapes.bowl_pieces())
    assert 0 < bowl < math.pi * shapes.BOWL_RIM_RADIUS**2 * shapes.BOWL_HEIGHT / 3
    disk = _volume(shapes.disk_pieces())
    ring = math.pi * (shapes.DISK_RADIUS**2 - shapes.DISK_HOLE_RADIUS**2) * shapes.DISK_THICKNESS
    assert disk == pytest.approx(ring, rel=0.05)
    assert _volume(shapes.stand_pieces()) > 0


def test_disk_hole_clears_the_rod():
    inner_apothem = shapes.DISK_HOLE_RADIUS * math.cos(math.pi / shapes.DISK_SEGMENTS)
    assert inner_apothem - shapes.ROD_RADIUS >= 0.005
    assert shapes.ROD_LENGTH > shapes.DISK_THICKNESS
