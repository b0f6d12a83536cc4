"""benchmarks/hanging_disk_colours.py: test scenes' disk colours and the per-colour breakdown."""

import json

from nerf_transporter.evaluation.metrics import summarize
from nerf_transporter.sim.fingerprint import world_fingerprint
from nerf_transporter.sim.tasks.hanging_disks import TEST_COLORS
from tests.helpers.benchmarks import load_benchmark


def test_test_scenes_draw_the_evaluation_colours_and_each_outcome_is_counted_once(tmp_path, capsys):
    script = load_benchmark("hanging_disk_colours")
    seeds = [1, 3, 5, 7, 9, 11]
    colours = script.scene_colours(seeds)
    assert colours == script.scene_colours(seeds)  # a function of the seed
    assert all(c["disk"] in TEST_COLORS and c["stand"] == "brown" for c in colours.values())
    results = [{"seed": s, "success": s in (1, 7), "error": None} for s in seeds]
    results[1]["failure"] = script.MISSED_PICK  # seed 3's pick touched nothing
    results.append({"seed": 13, "success": False, "error": "RuntimeError: cache"})  # left out
    identity = {"task": "hanging-disks", "setting": "normal", "method": "transporter_se2"}
    identity |= {"imagery": None}
    cell = identity | summarize(results) | {"world": world_fingerprint()}
    cell |= {
        "protocol": identity | {"colour_augment": True, "steps": 6000, "lr": 3e-4},
        "checkpoint": {"step": 6000},
        "episode_results": results,
    }
    counts = script.by_disk_colour(cell, colours)
    # this world's draw: seeds 1, 3, ..., 11 -> orange, pink, purple, white, green, blue; the
    # successes (seeds 1 and 7) are the orange and the white disk's
    assert [colours[seed]["disk"] for seed in seeds] == [
        "orange",
        "pink",
        "purple",
        "white",
        "green",
        "blue",
    ]
    assert counts == {
        "blue": [0, 1, 0],
        "red": [0, 0, 0],
        "green": [0, 1, 0],
        "orange": [1, 1, 0],
        "purple": [0, 1, 0],
        "pink": [0, 1, 1],
        "white": [1, 1, 0],
    }
    path = tmp_path / "transporter_se2.json"
    path.write_text(json.dumps(cell))
    assert script.main([str(path), "--json"]) == 0
    out = capsys.readouterr().out
    assert "| transporter_se2 +colour (6000 steps, lr 0.0003) | 2/6 (1) |" in out
    assert "| 0/1 (1) |" in out  # the pink disk's one episode, its pick missed
    assert json.loads(out.splitlines()[-1])["cells"][0]["by_disk"] == counts
    assert script.main([str(path), "--seeds", "5"]) == 0  # seeds 1 and 3 only
    assert (
        "| transporter_se2 +colour (6000 steps, lr 0.0003) | 1/2 (1) |" in capsys.readouterr().out
    )
    sweep = tmp_path / "sweep" / "transporter_se2.json"  # another fit of the same row
    sweep.parent.mkdir()
    sweep.write_text(json.dumps(cell))
    del cell["protocol"]["colour_augment"]  # a fit of the same row without it: its own label
    sweep.write_text(json.dumps(cell))
    assert script.main([str(path), str(sweep)]) == 0  # every file named is a row
    out = capsys.readouterr().out
    assert "| transporter_se2 +colour (6000 steps, lr 0.0003) | 2/6 (1) |" in out
    assert "| transporter_se2 | 2/6 (1) |" in out
    assert script.main([str(sweep), str(sweep)]) == 0  # the same label twice: named by its path
    assert f"| transporter_se2, {sweep} | 2/6 (1) |" in capsys.readouterr().out


def test_a_test_record_is_a_row_named_by_its_file_and_imagery(tmp_path):
    script = load_benchmark("hanging_disk_colours")
    record = {"path": tmp_path / "step002000-test-normal-nerf-sparsity_weight0.0003.json"}
    record |= {"imagery": "nerf", "imagery_options": {"sparsity_weight": 0.0003}}
    assert script.cell_label(record) == (
        "step002000-test-normal-nerf-sparsity_weight0.0003 (nerf imagery sparsity_weight=0.0003)"
    )
