"""`nerf-transporter evaluate-checkpoints`: every checkpoint of a run, closed loop on validation seeds."""

import json
import logging
from pathlib import Path

import pytest
import torch

from nerf_transporter.cli import main as cli_main
from nerf_transporter.experiments.checkpoints import chosen_checkpoints, evaluated_validation
from tests.helpers.state_run import trained_state_mlp


class Exploit:
    """Unpickling this runs code (it would create the file `exploited`)."""

    def __reduce__(self):
        return (Path.touch, (Path.cwd() / "exploited",))


def test_every_checkpoint_of_a_run_is_evaluated_and_the_best_named(
    tmp_path, capsys, caplog, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "logs" / "block-insertion" / "gt_state_mlp" / "version_0"
    trainer = trained_state_mlp(tmp_path)
    trainer.save_checkpoint(run / "checkpoints" / "step2.ckpt")
    trainer.save_checkpoint(run / "checkpoints" / "last.ckpt")  # the same step again
    later = torch.load(run / "checkpoints" / "step2.ckpt", weights_only=True)
    later["global_step"] = 4
    torch.save(later, run / "checkpoints" / "step4.ckpt")
    (run / "checkpoints" / "truncated.ckpt").write_bytes(b"PK\x03\x04 cut short")
    torch.save({"payload": Exploit()}, run / "checkpoints" / "pickled.ckpt")

    fitted_on = {"cpu": "the CPU run-cell fitted it on", "gpu": None}
    (run / "fit-segments.json").write_text(json.dumps([{"machine": fitted_on}]))

    argv = [str(run), "--split", "validation", "--episodes", "2", "--cache-dir", str(tmp_path)]
    with caplog.at_level(logging.WARNING):
        assert cli_main(["evaluate-checkpoints", *argv, "--json", "--eval-workers", "2"]) == 0
    # the unreadable and the unsafe checkpoints were skipped, named, and never unpickled
    assert "skipping unreadable checkpoint" in caplog.text
    assert "truncated.ckpt" in caplog.text and "pickled.ckpt" in caplog.text
    assert not (tmp_path / "exploited").exists()
    out = capsys.readouterr().out
    summary = json.loads(out.strip().splitlines()[-1])
    assert [c["global_step"] for c in summary["checkpoints"]] == [2, 4]
    assert all(c["episodes"] == 2 for c in summary["checkpoints"])
    # the two hold the same weights, so the same rate: among equals the latest is the best
    step2, step4 = summary["checkpoints"]
    assert step2["success_rate"] == step4["success_rate"]
    assert summary["best"] == step4["checkpoint"]
    assert f"lightning test --config <the run's config> --ckpt_path {summary['best']}" in out
    for name in ("step2", "step4"):
        record = json.loads((run / "evaluation" / f"{name}-validation-normal.json").read_text())
        assert record["method"] == "gt_state_mlp" and record["split"] == "validation"
        seeds = [episode["seed"] for episode in record["episode_results"]]
        assert seeds == [1_000_000, 1_000_001]
        # each record names the code and the machines it comes from
        assert len(record["git"]["commit"]) == 40
        assert record["machine"]["fit"] == [fitted_on]
        assert record["machine"]["test"]["cpu"] and record["machine"]["test"]["gpu"] is None
    # the records are written, so no episode journal is left to resume from
    assert not list((run / "evaluation" / ".journals").glob("*.jsonl"))
    # evaluating again adds files beside the first ones: nothing is replaced
    assert cli_main(["evaluate-checkpoints", *argv, "--eval-workers", "1"]) == 0
    assert (run / "evaluation" / "step2-validation-normal-2.json").is_file()
    # one checkpoint named: only it is evaluated; one outside the run is refused by name
    one = ["--checkpoint", str(run / "checkpoints" / "step4.ckpt"), "--eval-workers", "1"]
    assert cli_main(["evaluate-checkpoints", *argv, *one]) == 0
    assert (run / "evaluation" / "step4-validation-normal-3.json").is_file()
    assert not (run / "evaluation" / "step2-validation-normal-3.json").exists()
    # a bare file name names the run's checkpoint of that name
    named = chosen_checkpoints(run, [Path("step4.ckpt")])
    assert named == [(4, run / "checkpoints" / "step4.ckpt")]
    capsys.readouterr()
    stray = tmp_path / "stray.ckpt"
    stray.write_bytes((run / "checkpoints" / "step4.ckpt").read_bytes())
    assert cli_main(["evaluate-checkpoints", *argv, "--checkpoint", str(stray)]) == 2
    assert f"{stray} is not a checkpoint file inside the run" in capsys.readouterr().err


def test_a_run_without_checkpoints_is_an_error(tmp_path, capsys):
    assert cli_main(["evaluate-checkpoints", str(tmp_path)]) == 2
    assert "no readable .ckpt files" in capsys.readouterr().err


def test_eval_workers_must_be_positive(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli_main(["evaluate-checkpoints", str(tmp_path), "--eval-workers", "0"])
    assert exit_info.value.code == 2
    assert "--eval-workers must be >= 1" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("measured_under", "view_choice", "taken"),
    [
        ({}, "max_logit", True),
        ({"test_time_options": {"view_choice": "view_softmax"}}, "view_softmax", True),
        ({"test_time_options": {"view_choice": "view_softmax"}}, "max_logit", False),
        ({}, "view_softmax", False),
        ({"imagery_options": {"iterations": 20}}, "max_logit", False),
    ],
)
def test_a_validation_record_stands_for_a_round_only_under_the_fits_own_settings(
    tmp_path, measured_under, view_choice, taken
):
    """A fit validated after the fact (run-cell on a GPU fit) takes an `evaluate-checkpoints`
    record as its round only where it was measured under the fit's view choice and imagery."""
    checkpoint = tmp_path / "checkpoints" / "step000500.ckpt"
    record = {"checkpoint": str(checkpoint), "split": "validation", "setting": "normal"}
    record |= {"episodes": 20, "errors": 0, "success_rate": 0.25} | measured_under
    (tmp_path / "evaluation").mkdir()
    (tmp_path / "evaluation" / "step000500-validation-normal.json").write_text(json.dumps(record))
    found = evaluated_validation(tmp_path, checkpoint, 20, "normal", view_choice)
    assert (found == record) is taken and (found is None) is not taken
