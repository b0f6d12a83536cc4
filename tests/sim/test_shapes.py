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
    assert volume == pytest.approx(shapes.polygon_area(shape.outline) * 0.02)  # 2 cm thick


@pytest.mark.parametrize("name", sorted(shapes.KIT_SHAPES))
def test_kit_objects_have_the_anchors_size(name):
    """The anchor's kitting meshes: 5.7 cm along the longer side, 2 cm thick, origin at the
    bottom face."""
    points = np.concatenate(shapes.kit_object_pieces(shapes.KIT_SHAPES[name]))
    assert points[:, 2].min() == pytest.approx(0.0) and points[:, 2].max() == pytest.approx(0.02)
    assert np.ptp(points[:, :2], axis=0).max() == pytest.approx(0.057)


def test_kit_plate_is_the_anchors_box():
    assert shapes.KIT_PLATE_SIZE == (0.1, 0.1, 0.005)


def test_fan_pieces_are_convex():
    for shape in shapes.KIT_SHAPES.values():
        assert all(shapes.is_convex(piece) for piece in shapes.fan_pieces(shape.outline))


def test_bowl_has_the_anchors_rim_depth_and_origin_offset():
    """The anchor's cup mesh: rim 9.2-9.4 cm across, 5.6 cm tall from an underside in the origin's
    plane, its axis 2.15 cm off the origin; a cavity a 4 cm cube turns in, floored 1.45 cm up."""
    pieces = shapes.bowl_pieces()
    points = np.concatenate(pieces)
    low, high = points.min(axis=0), points.max(axis=0)
    assert (high - low)[:2].min() >= 0.092 and (high - low)[:2].max() <= 0.094 + 1e-9
    assert low[2] == pytest.approx(0.0) and high[2] == pytest.approx(0.056)
    axis = (low[:2] + high[:2]) / 2
    assert axis == pytest.approx([-0.0203, 0.0071], abs=1e-9)
    assert np.linalg.norm(axis) == pytest.approx(0.0215, abs=5e-4)
    inner_apothem = shapes.BOWL_INNER_RADIUS * math.cos(math.pi / shapes.BOWL_SEGMENTS)
    assert shapes.CUBE_SIZE / math.sqrt(2) < inner_apothem < shapes.CUBE_SIZE / 2 + 0.012
    assert shapes.bowl_seat() == pytest.approx([-0.0203, 0.0071, 0.0145 + 0.02])

    # closed pieces filling a foot and a straight wall (polygons of BOWL_SEGMENTS sides)
    def area(radius):
        return shapes.polygon_area(shapes.regular_polygon(shapes.BOWL_SEGMENTS, radius))

    foot = area(shapes.BOWL_FOOT_RADIUS) * shapes.BOWL_FLOOR_HEIGHT
    wall = (area(shapes.BOWL_RIM_RADIUS) - area(shapes.BOWL_INNER_RADIUS)) * (
        shapes.BOWL_HEIGHT - shapes.BOWL_FLOOR_HEIGHT
    )
    assert _volume(pieces) == pytest.approx(foot + wall)


def test_disk_is_the_anchors_ring_of_closed_pieces():
    """Outer radius 45 mm, hole 22.5 mm (polygon vertices on both), 10 mm thick about the origin."""
    pieces = shapes.disk_pieces()
    points = np.concatenate(pieces)
    radii = np.linalg.norm(points[:, :2], axis=1)
    assert radii.min() == pytest.approx(0.0225) and radii.max() == pytest.approx(0.045)
    assert (points[:, 2].min(), points[:, 2].max()) == pytest.approx((-0.005, 0.005))
    outer, hole = (shapes.regular_polygon(shapes.DISK_SEGMENTS, r) for r in (0.045, 0.0225))
    area = shapes.polygon_area(outer) - shapes.polygon_area(hole)
    assert _volume(pieces) == pytest.approx(area * 0.01)


def test_stand_is_the_anchors_plate_and_rod():
    """Plate 0.1 x 0.1 x 0.01 m centred on the origin (seen as a 5 cm box); rod of radius 5 mm,
    0.10 m long, centred 0.03 m up: tip 0.08 m up, 75 mm above the plate; a disk lies 0.01 m up."""
    visual, collision = shapes.stand_parts()
    plate, rod = collision
    assert plate.size == pytest.approx((0.1, 0.1, 0.01)) and plate.position == (0, 0, 0)
    assert visual[0].size == pytest.approx((0.05, 0.05, 0.01)) and visual[1] == rod
    assert (rod.radius, rod.length) == pytest.approx((0.005, 0.1))
    assert rod.position == pytest.approx((0, 0, 0.03))
    assert shapes.rod_tip_height() == pytest.approx(0.08)
    assert shapes.rod_tip_height() - plate.size[2] / 2 == pytest.approx(0.075)
    assert shapes.disk_rest_height() == pytest.approx(0.01)
    inner_apothem = shapes.DISK_HOLE_RADIUS * math.cos(math.pi / shapes.DISK_SEGMENTS)
    assert inner_apothem - rod.radius > 0.017  # the hole clears the rod by 17 mm
