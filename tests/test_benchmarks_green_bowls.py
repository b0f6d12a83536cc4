"""benchmarks/green_bowls.py: the view search scored against the green bowl a place went to."""

import json

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.evaluation.metrics import summarize
from nerf_transporter.sim.fingerprint import world_fingerprint
from tests.helpers.benchmarks import load_benchmark


def test_a_place_in_another_green_bowl_searched_in_its_view_counts_for_that_bowl(tmp_path, capsys):
    script = load_benchmark("green_bowls")
    bowls = script.scene_bowls("normal", [1, 3])
    assert bowls == script.scene_bowls("normal", [1, 3])  # a function of the seed
    assert [len(bowls[1]), len(bowls[3])] == [2, 3]  # this world's draw
    grid = g.view_grid("normal")
    origin, roll, pitch = bowls[3][1]  # seed 3's second bowl, not the one the label chose
    chosen = grid[g.nearest_view(roll, pitch, grid)]
    assert script.aimed_view_steps(origin, chosen, bowls[3], grid) == 0
    place = [*origin, 0.0, 0.0, 0.0, 1.0]
    results = [
        {  # placed in that bowl, in its view; the recorded true view 4 grid steps away
            "seed": 3,
            "success": True,
            "error": None,
            "action": {"pick": [0.5, 0.0, 0.02, 0, 0, 0, 1], "place": place},
            "view_search": {"chosen_view": [float(a) for a in chosen], "view_steps": 4},
        },
        {"seed": 1, "success": False, "error": None, "action": None},  # no search recorded
        {"seed": 5, "success": False, "error": "RuntimeError: cache"},  # erred: left out
    ]
    identity = {"task": "place-red-in-green", "setting": "normal", "method": "mira"}
    identity |= {"imagery": "nerf"}
    record = identity | summarize(results) | {"world": world_fingerprint()}
    record |= {"protocol": identity, "checkpoint": {"step": 2000}, "episode_results": results}
    counts = script.by_bowl_count(record, bowls | script.scene_bowls("normal", [5]))
    assert counts == {
        2: {"episodes": 1, "successes": 0, "searched": 0, "true_view": 0, "aimed_view": 0},
        3: {"episodes": 1, "successes": 1, "searched": 1, "true_view": 0, "aimed_view": 1},
    }
    path = tmp_path / "record.json"
    path.write_text(json.dumps(record))
    assert script.main([str(path), "--json"]) == 0
    out = capsys.readouterr().out
    assert f"| {path} | normal | 1/2; 0% / 100% | - | 0/1; - | 1/1; 0% / 100% |" in out
    assert json.loads(out.splitlines()[-1])[0]["all"]["aimed_view"] == 1
    assert np.isfinite(roll) and script.main([str(tmp_path / "missing.json")]) == 2
