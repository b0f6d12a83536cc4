"""benchmarks/flat_placement.py: its pose errors, aim and binning (no simulation)."""

import importlib.util
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from nerf_transporter import geometry as g

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def flat_placement():
    """The script as a module (registered while loading: its dataclass looks itself up there)."""
    spec = importlib.util.spec_from_file_location(
        "flat_placement", BENCHMARKS / "flat_placement.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(BENCHMARKS))  # the script imports its sibling device_info
    sys.modules[spec.name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(BENCHMARKS))
        sys.modules.pop(spec.name, None)


def test_pose_errors_in_the_fixture_frame(flat_placement):
    tolerance = flat_placement.TASKS["block-insertion"].tolerance
    target = (np.array([0.5, 0.0, 0.1]), g.euler_to_quat(0.0, math.radians(30), 0.0))
    rotation = g.quat_to_matrix(target[1])
    raised = (target[0] + 0.01 * rotation[:, 2], target[1])
    errors = flat_placement.pose_errors(raised, target, tolerance)
    assert errors["normal_offset_mm"] == pytest.approx(10.0)
    assert errors["in_plane_offset_mm"] == pytest.approx(0.0, abs=1e-9)
    assert errors["success"]
    diagonal = g.matrix_to_quat(
        rotation @ g.quat_to_matrix(g.euler_to_quat(math.radians(12), math.radians(12), 0.0))
    )
    errors = flat_placement.pose_errors((target[0], diagonal), target, tolerance)
    assert errors["tilt_error_deg"] == pytest.approx(12.0)
    assert errors["axis_tilt_error_deg"] > 16.0  # the task's max(|roll|, |pitch|) reads less


def test_aim_of_a_flat_block_carried_from_a_tilted_pick_point_is_downhill(flat_placement):
    target = (np.array([0.5, 0.0, 0.1]), g.euler_to_quat(0.0, math.radians(30), 0.0))
    block = (np.array([0.4, 0.2, 0.02]), np.array([0.0, 0.0, 0.0, 1.0]))
    pick = (block[0] + np.array([0.0, 0.0, 0.02]), np.array([0.0, 0.0, 0.0, 1.0]))
    tilted_place = g.multiply_poses(target, g.invert_pose(block), pick)
    flat_place = (tilted_place[0], np.array([0.0, 0.0, 0.0, 1.0]))
    task = SimpleNamespace(target_poses=[target], object_pose=lambda env: block)
    env = SimpleNamespace(task=task)
    tilted = flat_placement.aim(env, {"pick": pick, "place": tilted_place})
    flat = flat_placement.aim(env, {"pick": pick, "place": flat_place})
    assert tilted["aim_offset_mm"] == pytest.approx(0.0, abs=1e-9)
    assert flat["aim_downhill_mm"] == pytest.approx(20 * math.sin(math.radians(30)))
    assert flat["aim_offset_mm"] == pytest.approx(flat["aim_downhill_mm"])


def test_binned_rates(flat_placement):
    rows = [
        {"tilt": 5.0, "success": True},
        {"tilt": 25.0, "success": True},
        {"tilt": 27.0, "success": False},
    ]
    rates = flat_placement.binned_rates(rows, "tilt", (0, 10, 20, 30))
    assert list(rates) == ["0 to 10", "20 to 30"]
    assert (rates["20 to 30"]["successes"], rates["20 to 30"]["n"]) == (1, 2)
    with pytest.raises(ValueError, match="outside the bins"):
        flat_placement.binned_rates([{"tilt": 31.0, "success": True}], "tilt", (0, 10, 20, 30))
