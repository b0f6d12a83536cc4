"""`cache-imagery` builds each scene under the key that run-cell's test reads: the key of the
datamodule the fitted checkpoint holds, resolved from the task's config with the method's
overlay (which cache-imagery does not resolve), in the setting the test runs in."""

from pathlib import Path

import lightning
import pytest
import torch

from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.evaluation.rollout import EvaluationSpec
from nerf_transporter.experiments import cache_imagery
from nerf_transporter.experiments.run_cell import config_files, resolve_config

REPO = Path(__file__).resolve().parents[2]
CONFIGS = REPO / "configs"


def _checkpoint_datamodule(config: dict, path: Path) -> RavensDataModule:
    """The datamodule a fitted checkpoint of `config` gives back (`load_checkpoint`'s)."""
    datamodule = RavensDataModule(**config["data"]["init_args"])
    checkpoint = {
        "pytorch-lightning_version": lightning.__version__,
        "datamodule_hyper_parameters": dict(datamodule.hparams),
    }
    torch.save(checkpoint, path)
    return RavensDataModule.load_from_checkpoint(path, weights_only=True)


@pytest.mark.parametrize(
    ("task", "test_setting"),
    [("block-insertion", None), ("hanging-disks", "challenging"), ("stacking-kits", None)],
)
def test_cache_imagery_builds_under_the_key_a_mira_cells_test_reads(
    tmp_path, monkeypatch, task, test_setting
):
    cache = str(tmp_path / "cache")
    specs = []
    monkeypatch.setattr(
        cache_imagery,
        "cache_imagery",
        lambda spec, seeds, renderings, progress: specs.append(spec) or (0, 0.0),
    )
    argv = ["--task", task, "--episodes", "1", "--cache-dir", cache, "--configs", str(CONFIGS)]
    argv += ["--test-setting", test_setting] if test_setting else []
    assert cache_imagery.main(argv) == 0
    (built,) = specs
    fitted = resolve_config(config_files(CONFIGS, task, "normal", "mira"))
    assert fitted["model"]["class_path"].endswith("Mira")
    datamodule = _checkpoint_datamodule(fitted, tmp_path / "fitted.ckpt")
    # evaluate_checkpoints' spec, as run-cell's test asks it: the protocol's setting
    read = EvaluationSpec.from_datamodule(
        datamodule, split="test", setting=test_setting or "normal", cache_dir=cache
    )
    assert read.imagery == built.imagery == "nerf"
    assert (
        (read.task, read.setting) == (built.task, built.setting) == (task, test_setting or "normal")
    )
    assert read.imagery_key() == built.imagery_key()
