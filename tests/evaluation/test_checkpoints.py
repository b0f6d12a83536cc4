"""`nerf-transporter evaluate-checkpoints`: every checkpoint of a run, closed loop on validation seeds."""

import json
import logging
from pathlib import Path

import pytest
import torch
from lightning.pytorch.cli import LightningCLI
from torch.utils.data import DataLoader

from nerf_transporter.cli import main as cli_main
from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.methods import Method
from nerf_transporter.sim import make_env


class StateBatches(torch.utils.data.Dataset):
    """Random (state, pick, place) samples with unit quaternions: enough to take optimiser steps."""

    def __init__(self, state_dim):
        generator = torch.Generator().manual_seed(0)
        self.state = torch.randn(4, state_dim, generator=generator)
        self.poses = torch.randn(4, 2, 7, generator=generator)
        self.poses[..., 3:] = torch.nn.functional.normalize(self.poses[..., 3:], dim=-1)

    def __len__(self):
        return 4

    def __getitem__(self, index):
        pick, place = self.poses[index]
        return {"state": self.state[index], "pick": pick, "place": place}


class Exploit:
    """Unpickling this runs code (it would create the file `exploited`)."""

    def __reduce__(self):
        return (Path.touch, (Path.cwd() / "exploited",))


def test_every_checkpoint_of_a_run_is_evaluated_and_the_best_named(
    tmp_path, capsys, caplog, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    run = tmp_path / "logs" / "block-insertion" / "gt_state_mlp" / "version_0"
    state_dim = make_env("block-insertion").task.state_dim()
    cli = LightningCLI(
        Method,
        RavensDataModule,
        subclass_mode_model=True,
        run=False,
        save_config_callback=None,
        args={
            "model": {"class_path": "GTStateMLP", "init_args": {"state_dim": state_dim}},
            "data": {"task": "block-insertion", "imagery": "oracle", "data_dir": str(tmp_path)},
            "trainer": {"max_steps": 2, "logger": False, "enable_progress_bar": False},
        },
    )
    cli.trainer.fit(cli.model, train_dataloaders=DataLoader(StateBatches(state_dim), batch_size=2))
    cli.trainer.datamodule = cli.datamodule  # its hyper-parameters go into the checkpoints
    cli.trainer.save_checkpoint(run / "checkpoints" / "step2.ckpt")
    cli.trainer.save_checkpoint(run / "checkpoints" / "last.ckpt")  # the same step again
    later = torch.load(run / "checkpoints" / "step2.ckpt", weights_only=True)
    later["global_step"] = 4
    torch.save(later, run / "checkpoints" / "step4.ckpt")
    (run / "checkpoints" / "truncated.ckpt").write_bytes(b"PK\x03\x04 cut short")
    torch.save({"payload": Exploit()}, run / "checkpoints" / "pickled.ckpt")

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
    assert summary["best"] in {c["checkpoint"] for c in summary["checkpoints"]}
    assert f"lightning test --config <the run's config> --ckpt_path {summary['best']}" in out
    for name in ("step2", "step4"):
        record = json.loads((run / "evaluation" / f"{name}-validation-normal.json").read_text())
        assert record["method"] == "gt_state_mlp" and record["split"] == "validation"
        seeds = [episode["seed"] for episode in record["episode_results"]]
        assert seeds == [1_000_000, 1_000_001]
    # evaluating again adds files beside the first ones: nothing is replaced
    assert cli_main(["evaluate-checkpoints", *argv, "--eval-workers", "1"]) == 0
    assert (run / "evaluation" / "step2-validation-normal-2.json").is_file()


def test_a_run_without_checkpoints_is_an_error(tmp_path, capsys):
    assert cli_main(["evaluate-checkpoints", str(tmp_path)]) == 1
    assert "no readable .ckpt files" in capsys.readouterr().err


def test_eval_workers_must_be_positive(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli_main(["evaluate-checkpoints", str(tmp_path), "--eval-workers", "0"])
    assert exit_info.value.code == 2
    assert "--eval-workers must be >= 1" in capsys.readouterr().err
