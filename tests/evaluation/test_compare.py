"""`nerf-transporter compare-cells`: cells of one column paired on their common test seeds."""

import json

import pytest

from nerf_transporter.evaluation.compare import main
from nerf_transporter.evaluation.metrics import summarize


def write_cell(folder, name, outcomes, task="block-insertion", machine="AMD EPYC"):
    """A cell file as run-cell writes it, with these test outcomes (seed -> success or None for
    an erred episode)."""
    results = [
        {
            "seed": seed,
            "success": bool(won),
            "failure": None,
            "error": None if won is not None else "E",
        }
        for seed, won in outcomes.items()
    ]
    record = summarize([r for r in results if not r["error"]]) | {
        "protocol": {"task": task},
        "task": task,
        "setting": "normal",
        "method": "mira",
        "imagery": "nerf",
        "errors": sum(1 for r in results if r["error"]),
        "checkpoint": {"step": 2000},
        "machine": {"fit": [{"cpu": machine, "gpu": None}]},
        "episode_results": results,
    }
    path = folder / f"{name}.json"
    path.write_text(json.dumps(record))
    return path


def test_cells_are_paired_on_common_seeds_without_erred_episodes(tmp_path, capsys):
    first = write_cell(tmp_path, "first", {1: True, 3: True, 5: True, 7: False, 9: True, 11: False})
    other = write_cell(
        tmp_path, "other", {1: True, 3: False, 5: False, 7: False, 9: None, 13: True}
    )
    assert main([str(first), str(other)]) == 0
    rows = [line.strip("| ").split(" | ") for line in capsys.readouterr().out.splitlines()[2:]]
    assert rows[0][4:] == ["-"] * 6
    # common seeds without errors: 1, 3, 5, 7 -> both 1, first only 2, other only 0, neither 1
    assert rows[1][4:9] == ["4", "1", "2", "0", "1"]
    assert float(rows[1][9]) == pytest.approx(0.5)


def test_cells_of_different_columns_are_refused(tmp_path, capsys):
    first = write_cell(tmp_path, "first", {1: True})
    other = write_cell(tmp_path, "other", {1: True}, task="hanging-disks")
    assert main([str(first), str(other)]) == 2
    assert "different columns (block-insertion, hanging-disks)" in capsys.readouterr().err
    assert main([str(first)]) == 2
    assert "two or more cell files" in capsys.readouterr().err
    validation = tmp_path / "validation.json"
    validation.write_text(json.dumps(json.loads(first.read_text()) | {"split": "validation"}))
    assert main([str(first), str(validation)]) == 2
    assert "neither a run-cell cell nor a test record" in capsys.readouterr().err


def test_a_test_record_of_evaluate_checkpoints_is_compared_with_a_cell(tmp_path, capsys):
    cell = write_cell(tmp_path, "cell", {1: True, 3: False})
    record = json.loads(write_cell(tmp_path, "record", {1: True, 3: True, 5: True}).read_text())
    record |= {
        "split": "test",
        "checkpoint": "run/checkpoints/step004000.ckpt",
        "global_step": 4000,
    }
    record.pop("protocol"), record.pop("machine")
    tested = tmp_path / "step004000-test-normal.json"
    tested.write_text(json.dumps(record))
    assert main([str(cell), str(tested)]) == 0
    rows = [line.strip("| ").split(" | ") for line in capsys.readouterr().out.splitlines()[2:]]
    assert rows[1][2:9] == ["4000", "not recorded", "2", "1", "0", "1", "0"]
