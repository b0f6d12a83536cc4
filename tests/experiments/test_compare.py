"""`nerf-transporter compare-cells`: cells tested alike, paired on their common test seeds."""

import json

import pytest

from nerf_transporter.evaluation.metrics import summarize
from nerf_transporter.experiments.cells import cross_protocol, protocol_id
from nerf_transporter.experiments.compare import main
from nerf_transporter.sim.fingerprint import world_fingerprint


def write_cell(folder, name, outcomes, task="block-insertion", world=None, setting="normal"):
    """A cell file as run-cell writes it, with these test outcomes (seed -> success or None for
    an erred episode), tested in `setting` and measured in `world` (default: this checkout's)."""
    results = [
        {
            "seed": seed,
            "success": bool(won),
            "failure": None,
            "error": None if won is not None else "E",
        }
        for seed, won in outcomes.items()
    ]
    protocol = {"task": task, "setting": setting, "method": "mira", "imagery": "nerf"}
    record = summarize(results) | {
        "protocol": protocol,
        "world": world or world_fingerprint(),
        "task": task,
        "setting": setting,
        "method": "mira",
        "imagery": "nerf",
        "errors": sum(1 for r in results if r["error"]),
        "checkpoint": {"step": 2000, "path": "run/checkpoints/step002000.ckpt"},
        "machine": {"fit": [{"cpu": "AMD EPYC", "gpu": None}]},
        "episode_results": results,
    }
    path = folder / f"{name}.json"
    path.write_text(json.dumps(record))
    return path


def write_cross_cell(folder, name, outcomes, setting):
    """A cell as run-cell writes it for the Normal fit tested in `setting`."""
    fit = {"task": "block-insertion", "setting": "normal", "method": "mira", "imagery": "nerf"}
    protocol = cross_protocol(fit, setting)
    fitted = {
        "protocol_id": protocol_id(fit),
        "run_dir": "run",
        "checkpoint": "run/checkpoints/step002000.ckpt",
    }
    return edited(
        write_cell(folder, name, outcomes, setting=setting),
        lambda record: record.update(protocol=protocol, fit=fitted),
    )


def test_cells_are_paired_on_common_seeds_without_erred_episodes(tmp_path, capsys):
    first = write_cell(tmp_path, "first", {1: True, 3: True, 5: True, 7: False, 9: True, 11: False})
    other = write_cell(
        tmp_path, "other", {1: True, 3: False, 5: False, 7: False, 9: None, 13: True}
    )
    assert main([str(first), str(other)]) == 2  # tested on other seeds: refused unless asked
    err = capsys.readouterr().err
    assert f"{other} was tested on 6 seeds, {first} on 6, 5 of them common" in err
    assert "--allow-unequal-seeds" in err
    assert main([str(first), str(other), "--allow-unequal-seeds"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = [line.strip("| ").split(" | ") for line in lines[2:4]]
    assert rows[0][5:] == ["-"] * 6
    # common seeds without errors: 1, 3, 5, 7 -> both 1, first only 2, other only 0, neither 1
    assert rows[1][5:10] == ["4", "1", "2", "0", "1"]
    assert float(rows[1][10]) == pytest.approx(0.5)
    assert lines[5] == (
        f"{other}: paired on 4 seeds: the 5 both were tested on (this one 6, the first 6), less 1 "
        "that erred in either"
    )


def test_cells_trained_in_two_settings_are_paired_on_the_seeds_they_were_tested_on(
    tmp_path, capsys
):
    """The Normal fit tested on Challenging, and a fit trained on Challenging, on one seed set."""
    normal = write_cross_cell(tmp_path, "normal", {1: True, 3: False, 5: False}, "challenging")
    outcomes = {1: True, 3: True, 5: True}
    challenging = write_cell(tmp_path, "challenging", outcomes, setting="challenging")
    assert main([str(normal), str(challenging)]) == 0
    rows = [line.strip("| ").split(" | ") for line in capsys.readouterr().out.splitlines()[2:4]]
    assert [row[1] for row in rows] == ["Normal", "Challenging"]
    assert rows[1][5:10] == ["3", "1", "0", "2", "0"]
    normal_tested_normal = write_cell(tmp_path, "normal-normal", outcomes)
    assert main([str(normal_tested_normal), str(challenging)]) == 2
    err = capsys.readouterr().err
    assert "different tasks or settings (block-insertion, block-insertion Challenging)" in err


def test_cells_tested_on_different_tasks_are_refused(tmp_path, capsys):
    first = write_cell(tmp_path, "first", {1: True})
    other = write_cell(tmp_path, "other", {1: True}, task="hanging-disks")
    assert main([str(first), str(other)]) == 2
    assert "different tasks or settings (block-insertion, hanging-disks)" in capsys.readouterr().err
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
    assert main([str(cell), str(tested), "--allow-unequal-seeds"]) == 0
    rows = [line.strip("| ").split(" | ") for line in capsys.readouterr().out.splitlines()[2:4]]
    assert rows[1][1] == "Normal"
    assert rows[1][3:10] == ["4000", "not recorded", "2", "1", "0", "1", "0"]


def test_cells_of_two_worlds_are_refused_and_one_archived_world_is_compared(tmp_path, capsys):
    first = write_cell(tmp_path, "first", {1: True, 3: False})
    archive = tmp_path / "archive" / "world-0123456789abcdef"
    archive.mkdir(parents=True)
    old = write_cell(archive, "old", {1: True, 3: True}, world="0123456789abcdef")
    assert main([str(first), str(old)]) == 2
    err = capsys.readouterr().err
    assert f"measured in different worlds ({first} in {world_fingerprint()}" in err
    assert f"{old} in 0123456789abcdef" in err
    older = write_cell(archive, "older", {1: False, 3: True}, world="0123456789abcdef")
    assert main([str(old), str(older)]) == 0  # both of the archived world
    elsewhere = write_cell(tmp_path, "elsewhere", {1: True}, world="0123456789abcdef")
    assert main([str(first), str(elsewhere)]) == 2
    assert "was measured in world 0123456789abcdef" in capsys.readouterr().err


def edited(path, edit):
    """`path`'s cell after `edit(record)`."""
    record = json.loads(path.read_text())
    edit(record)
    path.write_text(json.dumps(record))
    return path


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (
            lambda r: [e.update(success="False") for e in r["episode_results"]],
            'episode_results[0]: success is "False", not true or false',
        ),
        (lambda r: r["episode_results"][1].pop("seed"), "episode_results[1] lacks seed"),
        (lambda r: r.pop("checkpoint"), "lacks checkpoint"),
        (lambda r: r.update(episode_results=None), "episode_results is null, not a list"),
    ],
    ids=["success-string", "no-seed", "no-checkpoint", "episodes-null"],
)
def test_a_cell_that_cannot_be_paired_is_named(tmp_path, capsys, edit, problem):
    """A string "False" is no success (bool() of it would pair 24 discordant seeds, p 1.2e-07)."""
    outcomes = dict.fromkeys(range(1, 49, 2), False)
    first = write_cell(tmp_path, "first", outcomes)
    other = edited(write_cell(tmp_path, "other", outcomes), edit)
    assert main([str(first), str(other)]) == 2
    err = capsys.readouterr().err
    assert f"nerf-transporter compare-cells: {other}" in err and problem in err, err
