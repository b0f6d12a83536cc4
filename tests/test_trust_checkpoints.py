"""Checkpoints are data, never code: a checkpoint whose hyper-parameters name any class but this
package's methods and DataModule is refused by every command that takes one, before anything it
names is imported; evaluate-checkpoints refuses an output it cannot write before the first episode
and says so plainly when no checkpoint could be loaded."""

import sys
from pathlib import Path

import pytest
import torch

from nerf_transporter.cli import lightning_main
from nerf_transporter.cli import main as cli_main
from nerf_transporter.evaluation import rollout
from nerf_transporter.experiments.checkpoints import (
    UntrustedCheckpointError,
    check_checkpoint_classes,
    load_checkpoint,
)
from nerf_transporter.pretrained import PRETRAINED_DIR
from tests.helpers.state_run import trained_state_mlp

REPO = Path(__file__).resolve().parents[1]
CONFIGS = [
    "--config",
    str(REPO / "configs" / "quick" / "block_insertion.yaml"),
    "--config",
    str(REPO / "configs" / "model" / "gt_state_mlp.yaml"),
]
INSTANTIATOR = "lightning.pytorch.cli.instantiate_module"
# a module that, imported, leaves the file `executed` beside it
EVIL_MODULE = """
from pathlib import Path

Path(__file__).with_name("executed").write_text("imported")


class Policy:
    pass


GTStateMLP = Policy
"""


@pytest.fixture
def evil_module(tmp_path, monkeypatch):
    """`evilpolicy.py` importable from the working folder (as from a `python -m` command's), and
    `this` (the Zen of Python) not yet imported; yields the marker file an import would write."""
    (tmp_path / "evilpolicy.py").write_text(EVIL_MODULE)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "argv", ["lightning"])
    for name in ("evilpolicy", "this"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    yield tmp_path / "executed"
    assert "evilpolicy" not in sys.modules and "this" not in sys.modules


def fake_checkpoint(path: Path, hyper_parameters: dict, **entries) -> Path:
    """A weights-only checkpoint file holding `hyper_parameters` (and `entries`)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"global_step": 2, "state_dict": {}, "hyper_parameters": hyper_parameters}
    torch.save(payload | entries, path)
    return path


@pytest.mark.parametrize("class_path", ["evilpolicy.Policy", "this.Zen"])
@pytest.mark.parametrize("command", ["test", "validate", "fit"])
def test_lightning_refuses_a_checkpoint_naming_foreign_code_without_importing_it(
    evil_module, tmp_path, capsys, class_path, command
):
    checkpoint = fake_checkpoint(
        tmp_path / "model.ckpt", {"_class_path": class_path, "_instantiator": INSTANTIATOR}
    )
    assert lightning_main([command, *CONFIGS, "--ckpt_path", str(checkpoint)]) == 2
    out, err = capsys.readouterr()
    assert not evil_module.exists()
    assert "Zen of Python" not in out
    assert f"--ckpt_path {checkpoint} names '{class_path}' in hyper_parameters._class_path" in err
    assert "Traceback" not in err
    assert not (tmp_path / "logs").exists()  # refused before any run folder is claimed


def test_a_class_path_nested_in_the_hyper_parameters_is_refused_too(evil_module, tmp_path, capsys):
    hyper_parameters = {
        "_class_path": "nerf_transporter.methods.GTStateMLP",
        "_instantiator": INSTANTIATOR,
        "extra": {"class_path": "evilpolicy.Policy"},
    }
    checkpoint = fake_checkpoint(tmp_path / "model.ckpt", hyper_parameters)
    assert lightning_main(["test", *CONFIGS, "--ckpt_path", str(checkpoint)]) == 2
    assert "in hyper_parameters.extra.class_path" in capsys.readouterr().err
    assert not evil_module.exists()


@pytest.mark.parametrize(
    ("entries", "named"),
    [
        (
            {"hyper_parameters": {"_class_path": "evilpolicy.GTStateMLP"}},
            "'evilpolicy.GTStateMLP' in hyper_parameters._class_path",
        ),
        (
            {
                "hyper_parameters": {"_class_path": "nerf_transporter.methods.GTStateMLP"},
                "datamodule_hyper_parameters": {"_class_path": "evilpolicy.Policy"},
            },
            "'evilpolicy.Policy' in datamodule_hyper_parameters._class_path",
        ),
    ],
    ids=["method", "datamodule"],
)
def test_evaluate_checkpoints_refuses_a_checkpoint_naming_foreign_code(
    evil_module, tmp_path, capsys, entries, named
):
    run = tmp_path / "run"
    checkpoint = fake_checkpoint(run / "checkpoints" / "step2.ckpt", **entries)
    assert cli_main(["evaluate-checkpoints", str(run), "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert f"{checkpoint} names {named}" in err and "every evaluation" not in err
    assert not evil_module.exists()
    assert not (run / "evaluation").exists()


def test_export_pretrained_refuses_a_checkpoint_naming_foreign_code(evil_module, tmp_path, capsys):
    checkpoint = fake_checkpoint(tmp_path / "model.ckpt", {"_class_path": "evilpolicy.Policy"})
    results = tmp_path / "results.json"
    results.write_text("{}")
    out = tmp_path / "package"
    out.mkdir()
    argv = ["export-pretrained", str(checkpoint), str(results), "--out", str(out)]
    assert cli_main([*argv, "--config", "c.yaml", "--commit", "abc"]) == 2
    err = capsys.readouterr().err
    assert f"{checkpoint} names 'evilpolicy.Policy'" in err and err.count("\n") == 1
    assert not evil_module.exists() and not any(out.iterdir())


def test_loading_a_checkpoint_refuses_a_foreign_instantiator(evil_module, tmp_path):
    """`try` and the benchmarks load checkpoints through `load_checkpoint`."""
    hyper_parameters = {
        "_class_path": "nerf_transporter.methods.GTStateMLP",
        "_instantiator": "evilpolicy.Policy",
    }
    checkpoint = fake_checkpoint(tmp_path / "model.ckpt", hyper_parameters)
    with pytest.raises(UntrustedCheckpointError, match=r"'evilpolicy.Policy' in hyper_param"):
        load_checkpoint(checkpoint, torch.device("cpu"))
    assert not evil_module.exists()


@pytest.mark.parametrize("path", sorted(PRETRAINED_DIR.glob("*.ckpt")), ids=lambda p: p.stem)
def test_the_shipped_policies_name_only_this_packages_classes(path):
    check_checkpoint_classes(path)


def test_evaluate_checkpoints_says_when_no_checkpoint_could_be_loaded(tmp_path, capsys):
    run = tmp_path / "run"
    # this package's method, without the weights or arguments it needs
    hyper_parameters = {"_class_path": "nerf_transporter.methods.GTStateMLP", "state_dim": "x"}
    first = fake_checkpoint(run / "checkpoints" / "step2.ckpt", hyper_parameters)
    second = fake_checkpoint(run / "checkpoints" / "step4.ckpt", hyper_parameters, global_step=4)
    assert cli_main(["evaluate-checkpoints", str(run), "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert f"none of the 2 checkpoints of {run} could be loaded, nothing was evaluated" in err
    assert str(first) in err and str(second) in err
    assert "erred" not in err


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory) -> Path:
    """A run folder with one checkpoint of a 2-step gt_state_mlp fit."""
    root = tmp_path_factory.mktemp("trained")
    run = root / "run"
    trained_state_mlp(root).save_checkpoint(run / "checkpoints" / "step2.ckpt")
    return run


def no_episode(*args, **kwargs):
    raise AssertionError("an episode was played")


@pytest.mark.parametrize(
    ("blocked", "extra", "named"),
    [
        ("run/evaluation", [], "the evaluation records' folder {run}/evaluation cannot be written"),
        ("videos", ["--video", "videos/run"], "--video videos/run cannot be written"),
    ],
    ids=["records", "video"],
)
def test_evaluate_checkpoints_refuses_an_unwritable_output_before_the_first_episode(
    trained_run, tmp_path, capsys, monkeypatch, blocked, extra, named
):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "step2.ckpt").write_bytes(
        (trained_run / "checkpoints" / "step2.ckpt").read_bytes()
    )
    monkeypatch.chdir(tmp_path)
    Path(blocked).write_text("a file where a folder should be")
    monkeypatch.setattr(rollout, "Evaluator", no_episode)  # what evaluate_policy plays with
    assert cli_main(["evaluate-checkpoints", str(run), "--episodes", "1", *extra]) == 2
    err = capsys.readouterr().err
    assert named.format(run=run) in err and "is not a folder" in err
    assert err.count("\n") == 1
