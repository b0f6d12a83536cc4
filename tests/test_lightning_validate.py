"""`lightning validate` of a run's checkpoint: the validation losses of its weights on the
validation samples, logged into the run."""

import sys

import pytest
import torch
from torch.utils.data import DataLoader

from nerf_transporter.cli import lightning_main
from nerf_transporter.cli import main as cli_main
from nerf_transporter.experiments.lightning_cli import build_cli
from nerf_transporter.methods import Mira
from tests.test_cli import SyntheticDataModule, tiny_config


class ValidatedDataModule(SyntheticDataModule):
    """The synthetic samples, also as two validation batches of two."""

    def val_dataloader(self) -> DataLoader:
        return DataLoader(self.samples, batch_size=2)


@pytest.fixture
def fitted(tmp_path, monkeypatch):
    """A 2-step tiny mira run in tmp_path: (config, checkpoint), one torch thread."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["lightning"])
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=2)
    text = config.read_text().replace(
        "tests.test_cli.SyntheticDataModule", f"{__name__}.ValidatedDataModule"
    )
    config.write_text(text)
    build_cli(["fit", "--config", str(config), "--trainer.limit_val_batches", "0"])
    (checkpoint,) = (tmp_path / "logs/block-insertion/mira/version_0/checkpoints").glob("*.ckpt")
    yield config, checkpoint
    torch.set_num_threads(threads)


def test_validate_reports_the_checkpoints_losses_on_the_validation_samples(fitted):
    config, checkpoint = fitted
    cli = build_cli(["validate", "--config", str(config), "--ckpt_path", str(checkpoint)])
    logged = cli.trainer.callback_metrics
    # the same losses by hand: the checkpoint's weights on the same samples, batch by batch
    model = Mira.load_from_checkpoint(checkpoint, weights_only=True).eval()
    batches = list(cli.datamodule.val_dataloader())
    with torch.no_grad():
        losses = [float(model.losses(batch)["loss"]) for batch in batches]
    assert len(batches) == 2
    assert float(logged["val/loss"]) == pytest.approx(sum(losses) / 2, rel=1e-5)
    assert losses[0] != pytest.approx(losses[1])  # two batches, so the mean is a real mean
    assert (checkpoint.parent.parent / "config-validate.yaml").is_file()  # logged into the run


def test_validate_through_the_console_script_exits_0(fitted):
    config, checkpoint = fitted
    assert (
        lightning_main(["validate", "--config", str(config), "--ckpt_path", str(checkpoint)]) == 0
    )


@pytest.mark.parametrize("entry", ["lightning", "nerf-transporter"])
def test_predict_is_refused_with_the_commands_that_judge_a_policy(entry, capsys):
    """A policy acts in closed loop: `predict` names `lightning test` and `evaluate-checkpoints`
    instead of Lightning's traceback about a missing `forward`."""
    argv = ["predict", "--config", "configs/quick/block_insertion.yaml", "--ckpt_path", "x.ckpt"]
    code = lightning_main(argv) if entry == "lightning" else cli_main(argv)
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("lightning predict: ")
    assert "lightning test --config" in err and "evaluate-checkpoints" in err
