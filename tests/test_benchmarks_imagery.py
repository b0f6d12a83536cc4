"""benchmarks/imagery.py: the grid's height error by view tilt."""

import numpy as np
import pytest

from nerf_transporter import geometry
from tests.helpers.benchmarks import load_benchmark


def test_height_error_is_binned_by_the_tilt_of_each_view():
    script = load_benchmark("imagery")
    normal, challenging = geometry.view_grid("normal"), geometry.view_grid("challenging")
    top_down_only = np.zeros(len(normal))
    top_down_only[geometry.top_down_view_index(normal)] = 7.0
    bins = script.mean_by_view_tilt(normal, list(top_down_only))
    assert bins["0-10"] == 7.0  # the 7 x 7 grid's only view under 10 deg is the top-down one
    assert list(bins) == ["0-10", "10-20", "20-30", "30-40", "40-90"]
    assert bins["10-20"] == bins["40-90"] == 0.0
    twenty = [v for v, view in enumerate(normal) if np.allclose(view, (np.radians(20.0), 0.0))]
    assert len(twenty) == 1
    only_twenty = np.zeros(len(normal))
    only_twenty[twenty] = 9.0
    assert script.mean_by_view_tilt(normal, list(only_twenty))["10-20"] == 0.0
    tilts = [np.degrees(np.arccos(geometry.tilt_matrix(*v)[2, 2])) for v in challenging]
    assert [script.view_tilt_deg(*v) for v in challenging] == pytest.approx(tilts)
    assert max(tilts) == pytest.approx(60.0)  # roll and pitch 45 deg
    steepest = [float(np.isclose(tilt, 60.0)) for tilt in tilts]  # the four 45 / 45 deg corners
    assert sum(steepest) == 4 and script.mean_by_view_tilt(challenging, steepest)["40-90"] > 0
    by_tilt = script.mean_by_view_tilt(challenging, tilts)
    for name, mean_tilt in by_tilt.items():
        low, high = map(float, name.split("-"))
        assert low <= mean_tilt < high
