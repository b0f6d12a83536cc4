"""The configs under configs/: composed with `__include__`, they resolve to the values the
hand-written task configs had at 8c67841; the model's pixel size and rotations come from the data
(LightningCLI links), gt_state_mlp's state length from the DataModule."""

import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from nerf_transporter.config_include import ConfigIncludeError, load_with_includes, merge
from nerf_transporter.experiments.lightning_cli import build_cli
from nerf_transporter.methods import METHODS
from nerf_transporter.sim import TASKS

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"
SUCCESS = "nerf_transporter.evaluation.callback.SuccessRateCallback"
CHECKPOINT = "lightning.pytorch.callbacks.ModelCheckpoint"
OFFLINE = "nerf_transporter.evaluation.view_probe.OfflineViewSearch"

# config name -> (task, setting, max_steps of the full config)
TASK_CONFIGS = {
    "block_insertion": ("block-insertion", "normal", 40000),
    "hanging_disks": ("hanging-disks", "normal", 9000),
    "place_red_in_green": ("place-red-in-green", "normal", 24000),
    "place_red_in_green_challenging": ("place-red-in-green", "challenging", 40000),
    "stacking_kits": ("stacking-kits", "normal", 20000),
}
# Resolved values of every task config as the hand-written YAMLs of 8c67841 gave them
# (`lightning fit --print_config`); the quick configs differ in QUICK.
FULL = {
    "seed_everything": 0,
    "trainer.log_every_n_steps": 50,
    "model.class_path": "nerf_transporter.methods.Mira",
    "model.init_args.lr": 1e-4,
    "model.init_args.pixel_size": 0.003125,
    "model.init_args.n_rotations": 36,
    "model.init_args.crop_size": 64,
    "model.init_args.width": 16,
    "model.init_args.feature_channels": 3,
    "model.init_args.view_chunk": 8,
    "model.init_args.log_images_every_n_steps": 250,
    "data.class_path": "nerf_transporter.data.datamodule.RavensDataModule",
    "data.init_args.n_demos": 10,
    "data.init_args.data_dir": "data",
    "data.init_args.batch_size": 1,
    "data.init_args.num_workers": 0,
    "data.init_args.imagery": "nerf",
    "data.init_args.pixel_size": 0.003125,
    "data.init_args.n_rotations": 36,
    "data.init_args.n_negative_views": 1,
    "data.init_args.negative_view_scale": 0.15,
    "data.init_args.augment": True,
    "data.init_args.samples_per_epoch": 1000,
    "data.init_args.imagery_config": None,
    "data.init_args.pin_memory": False,
}
QUICK = {
    "trainer.max_steps": 3000,
    "trainer.log_every_n_steps": 10,
    "model.init_args.lr": 1e-3,
    "model.init_args.pixel_size": 0.00625,
    "model.init_args.crop_size": 32,
    "model.init_args.width": 8,
    "model.init_args.log_images_every_n_steps": 100,
    "data.init_args.batch_size": 2,
    "data.init_args.pixel_size": 0.00625,
    "data.init_args.n_negative_views": 2,
    "data.init_args.samples_per_epoch": 100,
    "data.init_args.imagery_config": {"voxel_size": 0.00625, "iterations": 300},
}
CHECKPOINT_ARGS = {
    "monitor": "eval/success_rate",
    "mode": "max",
    "save_top_k": -1,
    "save_last": True,
    "filename": "step{step:06d}-success{eval/success_rate:.2f}",
    "auto_insert_metric_name": False,
}


@pytest.fixture(autouse=True)
def in_tmp_dir(tmp_path, monkeypatch):
    """Run in a temporary folder, as `lightning`, so that config paths resolve from elsewhere."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["lightning"])


def resolve(*names: str, extra: tuple[str, ...] = ()) -> tuple[dict, object]:
    """(flat resolved config, the CLI) of config files named relative to configs/."""
    argv = [arg for name in names for arg in ("--config", str(CONFIGS / name))]
    cli = build_cli([*argv, *extra], run=False)
    config = cli.config.clone()
    config.pop("config", None)
    return dict(config.items()), cli


def callbacks(config: dict) -> list[tuple[str, dict]]:
    return [(c.class_path, c.init_args.as_dict()) for c in config["trainer.callbacks"]]


@pytest.mark.parametrize("quick", [False, True], ids=["full", "quick"])
@pytest.mark.parametrize("name", list(TASK_CONFIGS))
def test_task_configs_resolve_to_the_values_of_8c67841(name, quick):
    task, setting, steps = TASK_CONFIGS[name]
    config, cli = resolve(f"quick/{name}.yaml" if quick else f"{name}.yaml")
    expected = {**FULL, "trainer.max_steps": steps, "data.init_args.task": task}
    expected["data.init_args.setting"] = setting
    expected |= QUICK if quick else {}
    assert {key: config[key] for key in expected} == expected
    every, episodes = (500, 5) if quick else (1000, 20)
    (success, success_args), (checkpoint, checkpoint_args), *probe = callbacks(config)
    # the full configs measure mira's view search offline between rounds; the quick ones do not
    assert probe == ([] if quick else [(OFFLINE, {"every_n_steps": 250, "demos": 10})])
    assert (success, success_args["every_n_steps"], success_args["episodes"]) == (
        SUCCESS,
        every,
        episodes,
    )
    assert checkpoint == CHECKPOINT
    assert checkpoint_args | CHECKPOINT_ARGS | {"every_n_train_steps": every} == checkpoint_args
    assert (cli.model.pixel_size, cli.model.n_rotations) == (
        cli.datamodule.pixel_size,
        cli.datamodule.n_rotations,
    )


@pytest.mark.parametrize("name", list(TASK_CONFIGS))
def test_the_quick_overlay_stacked_by_hand_is_the_quick_config(name):
    by_hand, _ = resolve(f"{name}.yaml", "common/quick.yaml")
    quick, _ = resolve(f"quick/{name}.yaml")
    assert by_hand == quick


@pytest.mark.parametrize("task_config", ["block_insertion.yaml", "quick/stacking_kits.yaml"])
def test_method_overlays_keep_the_task_settings(task_config):
    base, _ = resolve(task_config)
    shared = ("lr", "crop_size", "width", "log_images_every_n_steps")
    for name, cls in METHODS.items():
        config, cli = resolve(task_config, f"model/{name}.yaml")
        assert type(cli.model) is cls
        init_args = {key.split(".")[-1] for key in config if key.startswith("model.init_args.")}
        for key in init_args & set(shared):
            if (name, key) != ("gt_state_mlp", "lr"):
                assert config[f"model.init_args.{key}"] == base[f"model.init_args.{key}"]
        if name == "gt_state_mlp":
            assert config["model.init_args.lr"] == 1e-3
            assert set(cli.model.hparams) == {"_class_path", "_instantiator"} | init_args
        else:
            assert cli.model.pixel_size == config["data.init_args.pixel_size"]
        assert {k: v for k, v in config.items() if k.startswith(("data.", "trainer."))} == {
            k: v for k, v in base.items() if k.startswith(("data.", "trainer."))
        }


WHERE = {"trainer.accelerator", "trainer.devices"}  # gpu in the overlay, cpu from the command line
LOADER = {"data.init_args.num_workers", "data.init_args.pin_memory"}


@pytest.mark.parametrize(
    "stacked, expected",
    [
        (
            ("gpu/h100.yaml", "gpu/width64.yaml", "gpu/bf16.yaml", "gpu/no_pybullet.yaml"),
            WHERE | LOADER | {"trainer.precision", "trainer.callbacks", "model.init_args.width"},
        ),
        # none of these keys is part of a cell's protocol (cell.cell_protocol): same run folder
        (("gpu/shared.yaml",), WHERE | LOADER),
        (
            ("gpu/shared.yaml", "gpu/cuda_graphs.yaml"),
            WHERE | LOADER | {"model.init_args.cuda_graphs"},
        ),
    ],
)
def test_gpu_overlays_change_only_where_and_how_fast(stacked, expected):
    base, _ = resolve("quick/hanging_disks.yaml", "model/transporter_se3.yaml")
    config, cli = resolve(
        "quick/hanging_disks.yaml",
        "model/transporter_se3.yaml",
        *stacked,
        extra=("--trainer.accelerator", "cpu"),  # no GPU here
    )
    assert {key for key in config if config[key] != base.get(key)} == expected
    if "gpu/bf16.yaml" in stacked:
        assert (config["model.init_args.width"], config["trainer.precision"]) == (64, "bf16-mixed")
        assert callbacks(config) == [(CHECKPOINT, callbacks(config)[0][1])]


def test_the_model_takes_pixel_size_and_rotations_from_the_data():
    argv = ("--data.init_args.pixel_size", "0.0125", "--data.init_args.n_rotations", "12")
    for method in ("mira", "form2fit"):
        _, cli = resolve("block_insertion.yaml", f"model/{method}.yaml", extra=argv)
        assert (cli.model.pixel_size, cli.model.n_rotations) == (0.0125, 12)
        assert (cli.model.hparams["pixel_size"], cli.model.hparams["n_rotations"]) == (0.0125, 12)
    # a link target of one method is not a hyper-parameter of another
    assert "state_dim" not in cli.model.hparams


@pytest.mark.parametrize("task", sorted(TASKS))
def test_gt_state_mlp_takes_the_state_length_from_the_datamodule_without_a_batch(task):
    _, cli = resolve(f"{task.replace('-', '_')}.yaml", "model/gt_state_mlp.yaml")
    datamodule, model = cli.datamodule, cli.model
    datamodule.train_dataloader = None  # loading a batch would fail
    model.trainer = SimpleNamespace(datamodule=datamodule)  # what fit() has set by configure_model
    model.configure_model()
    assert model.hparams["state_dim"] == datamodule.state_dim == TASKS[task].state_dim()
    assert model.mlp.net[0].in_features == datamodule.state_dim


@pytest.mark.parametrize("name", list(METHODS))
def test_model_help_lists_every_argument_of_the_constructor_chain(name, capsys):
    cls = METHODS[name]
    with pytest.raises(SystemExit) as exit_info:
        build_cli(["fit", "--model.help", cls.__name__])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    arguments = {"lr", "log_images_every_n_steps"}
    if name == "gt_state_mlp":
        arguments |= {"state_dim", "hidden", "layers"}
    else:
        arguments |= {"pixel_size", "n_rotations", "crop_size", "width"}
    arguments |= {"view_chunk"} if name == "mira" else set()
    arguments |= {"regression_features"} if name == "transporter_se3" else set()
    arguments |= {"descriptor_dim", "margin"} if name == "form2fit" else set()
    for argument in arguments:
        assert f"--model.{argument} " in out, argument
    lr = 1e-3 if name == "gt_state_mlp" else 1e-4
    assert f"(type: float, default: {lr})" in out


def test_includes_merge_in_order_relative_to_the_including_file(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "a.yaml").write_text("x: {p: 1, q: [1, 2]}\ny: 1\nw: ${y}\n")
    (tmp_path / "parts" / "b.yaml").write_text("__include__: a.yaml\nx: {q: [3]}\ny: 2\n")
    text = "__include__: [parts/b.yaml]\nx: {r: 2}\n"
    expected = {"x": {"p": 1, "q": [3], "r": 2}, "y": 2, "w": 1}  # interpolated within a.yaml
    assert load_with_includes(text, tmp_path) == expected
    assert merge({"a": {"b": 1, "c": 2}}, {"a": {"b": 3}, "d": 4}) == {
        "a": {"b": 3, "c": 2},
        "d": 4,
    }


def test_include_errors_are_named(tmp_path, capsys):
    (tmp_path / "loop.yaml").write_text("__include__: loop.yaml\n")
    with pytest.raises(ConfigIncludeError, match="loop"):
        load_with_includes("__include__: loop.yaml\n", tmp_path)
    with pytest.raises(ConfigIncludeError, match="a path or a list of paths"):
        load_with_includes("__include__: {a: 1}\n", tmp_path)
    (tmp_path / "bad.yaml").write_text("__include__: missing.yaml\nseed_everything: 1\n")
    with pytest.raises(SystemExit) as exit_info:
        build_cli(["fit", "--config", str(tmp_path / "bad.yaml")])
    assert exit_info.value.code == 2
    assert "missing.yaml" in capsys.readouterr().err


def test_a_checkpoint_of_another_pixel_size_is_refused():
    trained = METHODS["transporter_se2"](pixel_size=0.0625, n_rotations=4, crop_size=8, width=8)
    checkpoint = {"hyper_parameters": dict(trained.hparams), "state_dict": trained.state_dict()}
    other = METHODS["transporter_se2"](pixel_size=0.125, n_rotations=4, crop_size=8, width=8)
    with pytest.raises(ValueError, match="trained with pixel_size 0.0625"):
        other.on_load_checkpoint(checkpoint)
    same = METHODS["transporter_se2"](**trained.hparams)
    same.on_load_checkpoint(checkpoint)
    same.load_state_dict(checkpoint["state_dict"])
    pairs = zip(same.state_dict().values(), trained.state_dict().values(), strict=True)
    assert all(torch.equal(a, b) for a, b in pairs)


# configs/recipe/: MIRA's value of each knob (its code), the table's where a file leaves it
MIRA_RECIPE = {
    "data.init_args.augment_distribution": "gaussian",
    "data.init_args.negative_transform": "own",
    "data.init_args.n_negative_views": 1,
    "data.init_args.negative_view_scale": None,
    "data.init_args.colour_augment": False,
    "model.init_args.view_choice": "view_softmax",
    "model.init_args.width": 64,
    "model.init_args.lr": 1e-4,
    "model.init_args.square_attention": True,
}
RECIPE_KNOBS = {
    "se2_gaussian.yaml": (
        "data.init_args.augment_distribution",
        "data.init_args.negative_transform",
    ),
    "negatives_uniform.yaml": ("data.init_args.negative_view_scale",),
    "no_colour_augment.yaml": ("data.init_args.colour_augment",),
    "view_softmax.yaml": ("model.init_args.view_choice",),
    "width64_lr1e-4.yaml": ("model.init_args.width",),  # the task configs' lr is MIRA's 1e-4
    "square_attention.yaml": ("model.init_args.square_attention",),
}


def test_mira_code_recipe_sets_every_knob_to_miras_value():
    config, _ = resolve("hanging_disks.yaml", "data/colour_augment.yaml", "recipe/mira_code.yaml")
    assert {key: config[key] for key in MIRA_RECIPE} == MIRA_RECIPE


@pytest.mark.parametrize("knob", list(RECIPE_KNOBS))
def test_each_recipe_knob_switches_alone(knob):
    base, _ = resolve("hanging_disks.yaml", "data/colour_augment.yaml")
    config, _ = resolve("hanging_disks.yaml", "data/colour_augment.yaml", f"recipe/{knob}")
    changed = {key for key in MIRA_RECIPE if config[key] != base[key]}
    assert changed == set(RECIPE_KNOBS[knob])
    assert all(config[key] == MIRA_RECIPE[key] for key in changed)


def test_the_shared_recipe_knobs_stack_on_transporter_se2():
    config, cli = resolve(
        "hanging_disks.yaml", "model/transporter_se2.yaml", "recipe/sampling.yaml"
    )
    assert type(cli.model).__name__ == "TransporterSE2"
    shared = [key for key in MIRA_RECIPE if key.startswith("data.")]
    assert {key: config[key] for key in shared} == {key: MIRA_RECIPE[key] for key in shared}


def test_the_imagery_overlays_train_on_data_of_their_own():
    """The default imagery (the table-colour start) and each overlay: data of its own; the
    reference overlay takes back the data every earlier cell was trained on."""
    clis = [
        resolve("hanging_disks.yaml", *overlay)[1]
        for overlay in ((), ("imagery/reference.yaml",), ("imagery/full_resolution_1600.yaml",))
    ]
    scenes = [cli.datamodule.generation_config("train").scene for cli in clis]
    assert [
        (s.imagery_config().colour_init, s.imagery_config().sparsity_weight) for s in scenes
    ] == [
        ("table", 0.0003),
        ("grey", 0.003),
        ("table", 0.0003),
    ]
    assert scenes[2].imagery_config().iterations == 1600
    names = [cli.datamodule.generation_config("train").dataset_name() for cli in clis]
    assert names[1] == "hanging-disks-normal-train"
    assert all(name.startswith("hanging-disks-normal-train-imagery") for name in names[::2])
    assert len(set(names)) == 3
