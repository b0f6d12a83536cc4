"""`nerf-transporter report`: the results table from results.json files."""

import json

import pytest

from nerf_transporter.cli import main as cli_main
from nerf_transporter.evaluation.report import main as report_main


def _write(root, run, method, task, setting, successes, episodes, low, high, created, name=None):
    path = root / run / "checkpoints" / (name or "results.json")
    path.parent.mkdir(parents=True)
    record = {
        "method": method,
        "task": task,
        "setting": setting,
        "split": "test",
        "episodes": episodes,
        "successes": successes,
        "success_rate": successes / episodes,
        "ci_low": low,
        "ci_high": high,
        "created": created,
    }
    path.write_text(json.dumps(record))


@pytest.fixture
def logs(tmp_path):
    root = tmp_path / "logs"
    _write(
        root,
        "bi/mira/version_0",
        "mira",
        "block-insertion",
        "normal",
        3,
        20,
        0.05,
        0.36,
        "2024-01-01T00:00:00",
    )
    # a newer run of the same cell replaces the older one
    _write(
        root,
        "bi/mira/version_1",
        "mira",
        "block-insertion",
        "normal",
        16,
        20,
        0.584,
        0.919,
        "2024-01-02T00:00:00",
    )
    _write(
        root,
        "bi/se2/version_0",
        "transporter_se2",
        "block-insertion",
        "normal",
        5,
        20,
        0.112,
        0.469,
        "2024-01-01T00:00:00",
    )
    _write(
        root,
        "prg/mira/version_0",
        "mira",
        "place-red-in-green",
        "challenging",
        50,
        100,
        0.4038,
        0.5962,
        "2024-01-01T00:00:00",
        name="results-challenging.json",  # a Normal-trained model tested in Challenging
    )
    _write(
        root,
        "bi-flat/se2/version_0",
        "transporter_se2",
        "block-insertion",
        "flat",
        20,
        20,
        0.839,
        1.0,
        "2024-01-01T00:00:00",
    )
    return root


EXPECTED = """\
| method | block-insertion | place-red-in-green | hanging-disks | stacking-kits | place-red-in-green Challenging | block-insertion Flat |
| --- | --- | --- | --- | --- | --- | --- |
| GT-State MLP |  |  |  |  |  |  |
| Form2Fit |  |  |  |  |  |  |
| Transporter-SE(2) | 25% (20, 11-47) |  |  |  |  | 100% (20, 84-100) |
| Transporter-SE(3) |  |  |  |  |  |  |
| mira (ours) | 80% (20, 58-92) |  |  |  | 50% (100, 40-60) |  |
"""


def test_report_renders_the_markdown_table(logs, capsys):
    assert cli_main(["report", str(logs)]) == 0
    assert capsys.readouterr().out == EXPECTED


def test_report_csv(logs, capsys):
    assert report_main([str(logs), "--csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == (
        "method,block-insertion,place-red-in-green,hanging-disks,stacking-kits,"
        "place-red-in-green Challenging,block-insertion Flat"
    )
    assert lines[3] == 'Transporter-SE(2),"25% (20, 11-47)",,,,,"100% (20, 84-100)"'


def test_report_without_results_says_what_to_run(tmp_path, capsys):
    assert report_main([str(tmp_path)]) == 1
    assert "lightning test" in capsys.readouterr().err


def test_report_names_a_corrupt_results_file(logs, capsys):
    bad = logs / "bi/mira/version_1/checkpoints/results.json"
    bad.write_text("{not json")
    assert report_main([str(logs)]) == 1
    assert str(bad) in capsys.readouterr().err
