"""benchmarks/place_views.py: the place view read back from a recorded mira action."""

import json
import math

import numpy as np

from nerf_transporter.data.labels import action_from_labels
from tests.helpers.benchmarks import load_benchmark


def recorded(action: dict) -> dict:
    """An action as an evaluation record stores it: position and quaternion in one list."""
    return {key: [*map(float, pos), *map(float, quat)] for key, (pos, quat) in action.items()}


def mira_action(view: tuple[float, float], place_pixel: tuple[int, int]) -> dict:
    return recorded(action_from_labels((100, 80), 0.02, place_pixel, 0.05, 7, place_view=view))


def test_place_views_beyond_the_training_grid_are_counted(tmp_path, capsys):
    script = load_benchmark("place_views")
    inside, steep = (math.radians(30), math.radians(-20)), (math.radians(45), math.radians(10))
    for view in (inside, steep):
        np.testing.assert_allclose(script.place_view(mira_action(view, (160, 80))), view, atol=1e-9)
    episodes = [
        {"seed": 1, "success": True, "error": None, "action": mira_action(inside, (160, 80))},
        {"seed": 3, "success": False, "error": None, "action": mira_action(steep, (319, 159))},
        {"seed": 5, "success": False, "error": "RuntimeError: x", "action": None},  # left out
    ]
    record = {"method": "mira", "setting": "challenging", "episode_results": episodes}
    counts = script.place_view_summary(record, math.radians(30))
    assert counts["episodes"] == 2 and counts["successes"] == 1
    assert counts["beyond_grid"] == 1 and counts["beyond_grid_successes"] == 0
    assert counts["outside_workspace"] == 1  # the steep view's far corner lands off the table
    path = tmp_path / "step100-test-challenging.json"
    path.write_text(json.dumps(record))
    assert script.main([str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])[0]["beyond_grid"] == 1
    path.write_text(json.dumps(record | {"method": "form2fit"}))
    assert script.main([str(path)]) == 1
    assert "is not a mira record" in capsys.readouterr().err
