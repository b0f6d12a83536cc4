"""`nerf-transporter run-cell`: protocol, skip, resume and the cell JSON (fit and test faked here;
the slow test at the end runs a tiny cell for real)."""

import functools
import itertools
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

from nerf_transporter.atomic import write_new_json
from nerf_transporter.data import observation
from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.device_info import describe_device
from nerf_transporter.evaluation.metrics import summarize
from nerf_transporter.evaluation.rollout import EvaluationSpec
from nerf_transporter.experiments import run_cell as cell_module
from nerf_transporter.experiments.cells import CellFileError, find_records, load_cell
from nerf_transporter.experiments.lightning_cli import build_cli, free_name
from nerf_transporter.experiments.report import results_table
from nerf_transporter.experiments.report import run_cell_command as command
from nerf_transporter.experiments.run_cell import CellError, apply_budget, resolve_config, run_cell
from nerf_transporter.geometry import view_grid
from nerf_transporter.methods import METHODS
from nerf_transporter.sim.fingerprint import world_fingerprint

REPO = Path(__file__).resolve().parents[2]
# the settings that change what is learned beyond the protocol's keys, at the table's values
TRAINING = {
    section: {
        key.split(".", 1)[1]: value
        for key, value in cell_module.TRAINING_DEFAULTS.items()
        if key.startswith(f"{section}.") and key != "data.class_path"
    }
    for section in ("trainer", "data")
}
CONFIG = {
    "seed_everything": 0,
    "trainer": {
        **TRAINING["trainer"],
        "max_steps": 40000,
        "callbacks": [
            {
                "class_path": "nerf_transporter.evaluation.callback.SuccessRateCallback",
                "init_args": {"every_n_steps": 1000, "episodes": 20},
            },
            {
                "class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
                "init_args": {"monitor": "eval/success_rate", "every_n_train_steps": 1000},
            },
        ],
    },
    "model": {"class_path": "nerf_transporter.methods.Mira", "init_args": {"lr": 1.0e-4}},
    "data": {
        "class_path": "nerf_transporter.data.datamodule.RavensDataModule",
        "init_args": {
            "task": "block-insertion",
            "setting": "normal",
            "n_demos": 10,
            "batch_size": 1,
            "imagery": "nerf",
            "pixel_size": 0.003125,
            "n_rotations": 36,
            "test_episodes": 100,
            **TRAINING["data"],
        },
    },
}
# validation success stored with each checkpoint; step 4's round had erred episodes (NaN -> -inf)
SCORES = {2: 0.5, 4: float("-inf"), 6: 0.5, 8: 0.25}
# validation successes (of 4) of a fit without closed-loop validation, counted afterwards
VALIDATION_SUCCESSES = {2: 1, 4: 3, 6: 3, 8: 2}


STEP_SECONDS = 10  # a training step of FakeLightning on a FakeClock


class FakeClock:
    """The cell module's `time.time` and `time.perf_counter`: `now`, moved on by the fakes and the
    test."""

    def __init__(self, now: float):
        self.now = now

    def time(self) -> float:
        return self.now

    perf_counter = time


class FakeLightning:
    """Stands in for `build_cli(["fit", ...])`: writes a checkpoint with its validation score every
    `every_n_train_steps` up to `max_steps` (or raises KeyboardInterrupt after `interrupt_at`).
    `build_cli(..., run=False)`, which resolves a config, is the real one."""

    def __init__(self):
        self.calls, self.configs, self.interrupt_at = [], [], None
        self.clock = None  # a FakeClock moved on by STEP_SECONDS a step, where given

    def __call__(self, args, **options):
        if options.get("run") is False:
            return build_cli(args, **options)
        config = yaml.safe_load(args[args.index("--config") + 1])  # the config's YAML text
        resume = args[args.index("--ckpt_path") + 1] if "--ckpt_path" in args else None
        self.calls.append(resume)
        self.configs.append(config)
        logger = config["trainer"]["logger"]["init_args"]
        folder = Path(logger["save_dir"], logger["version"], "checkpoints")
        folder.mkdir(parents=True, exist_ok=True)
        # the config, saved in the run folder as Lightning's RunConfigCallback does
        saved = folder.parent / free_name(folder.parent, "config", "fit")
        saved.write_text(args[args.index("--config") + 1])
        (saver,) = [
            c for c in config["trainer"]["callbacks"] if "ModelCheckpoint" in c["class_path"]
        ]
        every, monitor = (saver["init_args"].get(key) for key in ("every_n_train_steps", "monitor"))
        start = torch.load(resume, weights_only=True)["global_step"] if resume else 0
        for step in range(start + every, config["trainer"]["max_steps"] + 1, every):
            score = torch.tensor(SCORES[step]) if monitor else None
            state = {"monitor": monitor, "current_score": score}
            checkpoint = {"global_step": step, "callbacks": {"ModelCheckpoint{...}": state}}
            torch.save(checkpoint, folder / f"step{step:06d}.ckpt")
            torch.save(checkpoint, folder / "last.ckpt")
            if self.clock is not None:
                self.clock.now += STEP_SECONDS * every
                for name in (f"step{step:06d}.ckpt", "last.ckpt"):
                    os.utime(folder / name, (self.clock.now, self.clock.now))
            if step == self.interrupt_at:
                raise KeyboardInterrupt


def fake_test(run_dir, split, episodes, *, only, errors=0, setting=None, **kwargs):
    """Stands in for `evaluate_checkpoints`: on test seeds 1, 3, 5, ... every other one succeeds;
    on validation seeds the first `VALIDATION_SUCCESSES[step]`, recorded as the real one does (in
    `setting`, default Normal)."""
    records = []
    for path in only:
        step = torch.load(path, weights_only=True)["global_step"]
        wins = VALIDATION_SUCCESSES[step] if split == "validation" else None
        outcomes = [i < wins if wins is not None else i % 2 == 0 for i in range(episodes)]
        results = [
            {"seed": 2 * i + 1, "success": won, "failure": None if won else "missed"}
            for i, won in enumerate(outcomes)
        ]
        for result in results[:errors]:
            result |= {"success": False, "error": "ValueError: broken cache"}
        setting = setting or "normal"
        record = {"checkpoint": str(path), "global_step": step, "split": split, "setting": setting}
        record |= {"world": world_fingerprint(), **summarize(results), "episode_results": results}
        if split == "validation":
            write_new_json(run_dir / "evaluation", f"{path.stem}-{split}-{setting}", record)
        records.append(record)
    return records


@pytest.fixture
def fakes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    lightning = FakeLightning()
    monkeypatch.setattr(cell_module, "resolve_config", lambda files: CONFIG)
    monkeypatch.setattr(cell_module, "build_cli", lightning)
    monkeypatch.setattr(cell_module, "evaluate_checkpoints", fake_test)
    return lightning


def run(**options):
    arguments = dict(
        task="block-insertion",
        method="mira",
        imagery="oracle",
        steps=8,
        val_every=2,
        val_episodes=4,
        episodes=3,
        config_dir=REPO / "configs",
        device="cpu",
    )
    return run_cell(**(arguments | options))


@functools.cache
def _resolved(files: tuple[Path, ...]) -> str:
    return json.dumps(resolve_config(list(files)))


def real_config(files: list[Path]) -> dict:
    """`resolve_config(files)`, the real one (each file list resolved once per session)."""
    return json.loads(_resolved(tuple(files)))


@pytest.mark.parametrize("method", list(METHODS))
def test_each_method_is_fitted_as_its_own_class_from_the_real_configs(fakes, monkeypatch, method):
    monkeypatch.setattr(cell_module, "resolve_config", real_config)
    imagery = "oracle" if METHODS[method].input_kind == "imagery" else None
    _, stored = run(method=method, imagery=imagery)
    (fitted,) = fakes.configs
    class_path = f"nerf_transporter.methods.{METHODS[method].__name__}"
    assert fitted["model"]["class_path"] == stored["config"]["model"]["class_path"] == class_path
    assert stored["method"] == method


def test_an_overlay_replacing_the_model_is_refused_before_anything_runs(fakes, monkeypatch, capsys):
    monkeypatch.setattr(cell_module, "resolve_config", real_config)
    overlay = Path("other-model.yaml")
    overlay.write_text("model:\n  class_path: nerf_transporter.methods.TransporterSE2\n")
    assert cell_module.main(CELL_ARGV + ["--config", str(overlay)]) == 2
    err = capsys.readouterr().err
    assert "the config's model is nerf_transporter.methods.TransporterSE2, not mira's" in err
    assert fakes.calls == [] and not Path("logs").exists()


def test_a_cell_resumes_its_fit_skips_when_measured_and_refuses_another_protocol(
    fakes, monkeypatch
):
    fakes.clock = FakeClock(1000.0)
    monkeypatch.setattr(cell_module, "time", fakes.clock)

    def test_taking_30_s(*args, **kwargs):
        fakes.clock.now += 30
        return fake_test(*args, **kwargs)

    monkeypatch.setattr(cell_module, "evaluate_checkpoints", test_taking_30_s)
    fakes.interrupt_at = 4
    with pytest.raises(KeyboardInterrupt):
        run()  # steps 1-4 in 40 s, killed
    fakes.clock.now += 500  # until the same command runs again
    cell = Path("results/block-insertion/mira-oracle.json")
    assert not cell.exists()
    (runs,) = Path("logs/cells/block-insertion/mira-oracle").iterdir()  # one protocol folder
    run_dir = runs / "version_0"
    assert json.loads((run_dir / "fit-segments.json").read_text())[0]["wall_s"] is None

    fakes.interrupt_at = None
    path, record = run()  # resumes the interrupted fit in its folder, from its furthest step
    assert path == cell and fakes.calls == [None, str(run_dir / "checkpoints" / "step000004.ckpt")]
    assert sorted(p.name for p in runs.glob("version_*")) == ["version_0"]
    stored = json.loads(cell.read_text())
    assert stored == json.loads(json.dumps(record))
    assert stored["protocol"] == {
        "task": "block-insertion",
        "setting": "normal",
        "method": "mira",
        "imagery": "oracle",
        "n_demos": 10,
        "steps": 8,
        "batch_size": 1,
        "lr": 1.0e-4,
        "pixel_size": 0.003125,
        "n_rotations": 36,
        "validation_every": 2,
        "validation_episodes": 4,
        "test_episodes": 3,
        "model": {},
    }
    # the best validation round without errors; of two equal ones the later
    assert stored["checkpoint"] == {
        "path": str(run_dir / "checkpoints" / "step000006.ckpt"),
        "step": 6,
        "validation_success_rate": 0.5,
        "validation_successes": 2,
        "validation_episodes": 4,
    }
    assert [r["success_rate"] for r in stored["validation"]] == [0.5, None, 0.5, 0.25]
    assert (stored["episodes"], stored["successes"], stored["errors"]) == (3, 2, 0)
    assert stored["test_seeds"] == [1, 3, 5]
    assert stored["ci_low"] < 2 / 3 < stored["ci_high"]
    assert stored["config"]["trainer"]["max_steps"] == 8
    assert stored["config"]["data"]["init_args"]["imagery"] == "oracle"
    assert stored["machine"] == {
        "fit": [describe_device("cpu")] * 2,
        "test": describe_device("cpu"),
    }
    assert stored["world"] == world_fingerprint() and stored["torch"] == torch.__version__
    # steps 1-4 and 5-8, 40 s each; not the 500 s between the kill and the rerun
    assert (stored["train_wall_s"], stored["test_wall_s"]) == (80, 30)
    # the report reads the cell into its own row
    header, rows = results_table(find_records([Path("results")]).records)
    assert rows[2][:2] == ["mira, oracle imagery", "67% (3, 21-94) / -"]

    assert run() == (cell, None)  # measured: skipped, nothing fitted
    assert len(fakes.calls) == 2
    with pytest.raises(CellError, match="steps 8 there, 10 here"):
        run(steps=10)
    legacy = stored | {"protocol": {k: v for k, v in stored["protocol"].items() if k != "model"}}
    cell.write_text(json.dumps(legacy))  # written before the protocol had the model's entry
    assert run() == (cell, None)
    wider = {**CONFIG, "model": CONFIG["model"] | {"init_args": {"lr": 1.0e-4, "width": 64}}}
    monkeypatch.setattr(cell_module, "resolve_config", lambda files: wider)
    with pytest.raises(CellError, match=r"model \{\} there, \{'width': 64\} here"):
        run()
    graphed = CONFIG["model"] | {"init_args": {"lr": 1.0e-4, "cuda_graphs": True}}
    graphed = {**CONFIG, "model": graphed}
    monkeypatch.setattr(cell_module, "resolve_config", lambda files: graphed)
    assert run() == (cell, None)  # CUDA graphs change how, not what: the same cell
    monkeypatch.setattr(cell_module, "resolve_config", lambda files: CONFIG)

    created = stored["created"]
    time.sleep(1)
    path, record = run(force=True)  # a fresh fit in a new run folder
    assert fakes.calls[-1] is None and record["run_dir"].endswith("version_1")
    assert json.loads(cell.read_text())["created"] != created


def test_a_sweep_cell_names_every_setting_it_changes_from_the_tables_cell(fakes, capsys):
    """A sweep meant to change one knob says, before it fits, every setting in which it differs
    from the table's cell of its row and column: an overlay of the cell's left out shows."""
    run(table=Path("results"))  # the table's cell itself: nothing to compare with
    assert "differs from the table's cell" not in capsys.readouterr().out
    run(results=Path("sweep"), lr=0.0003, table=Path("results"))
    out = capsys.readouterr().out
    assert (
        "this protocol differs from the table's cell results/block-insertion/mira-oracle.json "
        "in lr (the cell: " in out
    )
    assert "this: 0.0003)" in out and "steps" not in out  # only what differs
    run(results=Path("sweep"), lr=0.0003, table=Path("results"))  # measured: skipped, silent
    assert "differs" not in capsys.readouterr().out


def test_an_interrupted_force_resumes_its_own_fit_and_a_finished_one_fits_afresh(fakes):
    run()
    runs = next(Path("logs/cells/block-insertion/mira-oracle").iterdir())
    cell = Path("results/block-insertion/mira-oracle.json")
    fakes.interrupt_at = 4
    with pytest.raises(KeyboardInterrupt):
        run(force=True)
    assert json.loads(cell.read_text())["run_dir"].endswith("version_0")  # the old cell stays
    fakes.interrupt_at = None
    _, record = run(force=True)  # resumes the forced fit, not the old one nor a fresh one
    assert fakes.calls[-1] == str(runs / "version_1" / "checkpoints" / "step000004.ckpt")
    assert record["run_dir"].endswith("version_1")
    _, record = run(force=True)  # its cell landed: the next --force fits afresh
    assert fakes.calls[-1] is None and record["run_dir"].endswith("version_2")
    assert sorted(p.name for p in runs.glob("version_*")) == [f"version_{i}" for i in range(3)]


def test_a_fit_without_pybullet_is_validated_where_the_cell_is_tested(fakes, monkeypatch):
    run_dir, record = run(fit_only=True)
    assert record is None and run_dir.name == "version_0" and len(fakes.calls) == 1
    callbacks = [c["class_path"] for c in fakes.configs[0]["trainer"]["callbacks"]]
    assert callbacks == ["lightning.pytorch.callbacks.ModelCheckpoint"]
    assert not Path("results").exists() and not (run_dir / "evaluation").exists()
    assert run(fit_only=True) == (run_dir, None) and len(fakes.calls) == 1  # fit done: kept

    evaluated, interrupt = [], [True]

    def interrupted_once(run_dir, split, episodes, *, only, **kwargs):
        if split == "validation" and interrupt:
            interrupt.clear()
            only = only[:2]
            fake_test(run_dir, split, episodes, only=only, **kwargs)
            evaluated.extend((split, path.name) for path in only)
            raise KeyboardInterrupt
        evaluated.extend((split, path.name) for path in only)
        return fake_test(run_dir, split, episodes, only=only, **kwargs)

    monkeypatch.setattr(cell_module, "evaluate_checkpoints", interrupted_once)
    with pytest.raises(KeyboardInterrupt):
        run()
    path, stored = run()  # validates the two rounds left, then tests the best
    assert len(fakes.calls) == 1  # not fitted again
    rounds = [f"step{step:06d}.ckpt" for step in (2, 4, 6, 8)]
    assert evaluated == [("validation", name) for name in rounds] + [("test", rounds[2])]
    assert [r["success_rate"] for r in stored["validation"]] == [0.25, 0.75, 0.75, 0.5]
    assert stored["checkpoint"]["step"] == 6 and stored["checkpoint"]["validation_successes"] == 3


def settings_tested(monkeypatch):
    """The (split, setting) of every `evaluate_checkpoints` call from here on (fake_test's)."""
    calls = []

    def recorded(run_dir, split, episodes, *, only, setting=None, **kwargs):
        calls.append((split, setting))
        return fake_test(run_dir, split, episodes, only=only, setting=setting, **kwargs)

    monkeypatch.setattr(cell_module, "evaluate_checkpoints", recorded)
    return calls


def test_a_challenging_cell_tests_the_normal_cells_fit_and_checkpoint_and_names_it(
    fakes, monkeypatch
):
    calls = settings_tested(monkeypatch)
    path, cross = run(test_setting="challenging")  # first: it fits as the Normal cell would
    assert path == Path("results/block-insertion-challenging/mira-oracle.json")
    assert len(fakes.calls) == 1 and fakes.configs[0]["data"]["init_args"]["setting"] == "normal"
    # validated on Normal validation seeds, tested on Challenging test seeds
    assert calls == [("test", "challenging")]  # the fit's rounds stored with its checkpoints
    spec = EvaluationSpec.from_datamodule(
        RavensDataModule("block-insertion", imagery="oracle"), split="test", setting=calls[0][1]
    )
    assert spec.grid.shape == (121, 2) and (spec.grid == view_grid("challenging")).all()

    normal_path, normal = run()  # the Normal cell: the same fit, never fitted again
    assert normal_path == Path("results/block-insertion/mira-oracle.json")
    assert len(fakes.calls) == 1 and calls[1:] == [("test", "normal")]
    assert "trained_setting" not in normal["protocol"] and "fit" not in normal
    fit_id = cell_module.protocol_id(normal["protocol"])
    assert normal["protocol_id"] == fit_id == cross["fit"]["protocol_id"]
    assert cross["protocol"] == normal["protocol"] | {
        "setting": "challenging",
        "trained_setting": "normal",
        "fit_protocol_id": fit_id,
    }
    assert (cross["setting"], cross["run_dir"]) == ("challenging", normal["run_dir"])
    assert cross["checkpoint"] == normal["checkpoint"] and cross["checkpoint"]["step"] == 6
    assert cross["fit"] == {
        "protocol_id": fit_id,
        "run_dir": normal["run_dir"],
        "checkpoint": normal["checkpoint"]["path"],
    }
    assert cross["validation"] == normal["validation"] and cross["config"] == normal["config"]
    assert Path(normal["run_dir"]).parent.parent == Path("logs/cells/block-insertion/mira-oracle")

    assert run(test_setting="challenging") == (path, None)  # measured: skipped
    _, again = run(test_setting="challenging", force=True)  # tested again, never fitted again
    assert len(fakes.calls) == 1 and calls[-1] == ("test", "challenging")
    assert again["fit"] == cross["fit"]
    # the cell loader reads both, each into its own column
    header, rows = results_table(find_records([Path("results")]).records)
    assert header[1:3] == ["block-insertion", "block-insertion Challenging"]
    assert rows[2][1:3] == ["67% (3, 21-94) / -"] * 2


def test_a_challenging_cell_resumes_an_unfinished_normal_fit_in_its_folder(fakes, monkeypatch):
    fakes.interrupt_at = 4
    with pytest.raises(KeyboardInterrupt):
        run()  # the Normal cell, interrupted
    fakes.interrupt_at = None
    _, cross = run(test_setting="challenging")
    (run_dir,) = Path("logs/cells/block-insertion/mira-oracle").glob("*/version_*")
    assert fakes.calls == [None, str(run_dir / "checkpoints" / "step000004.ckpt")]
    assert fakes.configs[0] == fakes.configs[1]  # resumed with the Normal cell's own config
    assert cross["run_dir"] == str(run_dir)
    _, normal = run()
    assert len(fakes.calls) == 2 and normal["run_dir"] == str(run_dir)
    with pytest.raises(CellError, match="unknown test setting 'tilted'"):
        run(test_setting="tilted")
    argv = CELL_ARGV + ["--test-setting", "challenging"]
    assert cell_module.main(argv) == 0 and len(fakes.calls) == 2  # measured: skipped


def test_a_challenging_cell_tests_the_fit_its_normal_cell_names_not_a_later_refit(
    fakes, monkeypatch, capsys
):
    calls = settings_tested(monkeypatch)
    _, normal = run()
    fakes.interrupt_at = 4
    with pytest.raises(KeyboardInterrupt):
        run(force=True)  # a refit, killed: the latest run folder, unfinished
    fakes.interrupt_at = None
    _, cross = run(test_setting="challenging")
    assert len(fakes.calls) == 2  # the abandoned refit is neither trained on nor tested
    assert cross["fit"] == {
        "protocol_id": normal["protocol_id"],
        "run_dir": normal["run_dir"],
        "checkpoint": normal["checkpoint"]["path"],
    }
    assert cross["checkpoint"] == normal["checkpoint"] and calls[-1] == ("test", "challenging")

    Path(normal["checkpoint"]["path"]).unlink()  # the Normal cell's fit is gone
    assert cell_module.main(CELL_ARGV + ["--test-setting", "challenging", "--force"]) == 2
    err = capsys.readouterr().err
    assert (
        f"results/block-insertion/mira-oracle.json was measured with {normal['checkpoint']['path']}"
        in err
    )
    assert "no such checkpoint" in err and len(fakes.calls) == 2


def test_a_challenging_cell_of_a_fit_its_normal_cell_no_longer_names_is_not_skipped(fakes, capsys):
    run()
    _, old = run(test_setting="challenging")
    _, refit = run(force=True)  # the Normal cell measured again, from a fresh fit
    assert cell_module.main(CELL_ARGV + ["--test-setting", "challenging"]) == 2
    err = capsys.readouterr().err
    assert f"tested {old['fit']['checkpoint']}, and results/block-insertion/mira-oracle.json" in err
    assert f"now names {refit['checkpoint']['path']}: --force tests that checkpoint" in err
    _, cross = run(test_setting="challenging", force=True)
    assert cross["fit"]["checkpoint"] == refit["checkpoint"]["path"] != old["fit"]["checkpoint"]
    path = Path("results/block-insertion-challenging/mira-oracle.json")
    assert run(test_setting="challenging") == (path, None)  # measured from the refit: skipped


def test_the_cell_loader_checks_that_a_cross_setting_cell_names_its_fit(fakes):
    path, cross = run(test_setting="challenging")
    stored = json.loads(path.read_text())
    edits = {
        "fit_protocol_id 0123456789ab is not the id": {
            "protocol": stored["protocol"] | {"fit_protocol_id": "0123456789ab"}
        },
        "its fit's checkpoint other.ckpt is not the checkpoint it tested": {
            "fit": stored["fit"] | {"checkpoint": "other.ckpt"}
        },
        "its fit's protocol_id 0123456789ab is not": {
            "fit": stored["fit"] | {"protocol_id": "0123456789ab"}
        },
        "needs trained_setting, fit_protocol_id in its protocol and its fit": {"fit": None},
        "trained_setting challenging is the setting it was tested in": {
            "protocol": stored["protocol"] | {"trained_setting": "challenging"}
        },
    }
    for problem, edit in edits.items():
        edited = {key: value for key, value in (stored | edit).items() if value is not None}
        path.write_text(json.dumps(edited))
        with pytest.raises(CellFileError, match=problem):
            load_cell(path)
    path.write_text(json.dumps(stored))
    moved = Path("results/block-insertion/mira-oracle.json")
    moved.parent.mkdir()
    moved.write_text(json.dumps(stored))
    with pytest.raises(CellFileError, match="holds the cell block-insertion-challenging/mira"):
        find_records([Path("results")])


def test_a_cell_records_the_commit_it_started_from(fakes, monkeypatch):
    """A commit made while a cell runs is not the code its validation and test ran."""
    calls = itertools.count()
    monkeypatch.setattr(
        cell_module, "git_state", lambda: {"commit": f"call {next(calls)}", "dirty": False}
    )
    _, stored = run()
    assert stored["git"]["commit"] == "call 0"
    assert [segment["commit"] for segment in stored["fit_git"]] == ["call 1"]


def test_a_test_with_erred_episodes_writes_no_cell_and_is_tested_again(fakes, monkeypatch, capsys):
    monkeypatch.setattr(
        cell_module, "evaluate_checkpoints", lambda *a, **k: fake_test(*a, errors=1, **k)
    )
    argv = ["--task", "block-insertion", "--method", "mira", "--steps", "8"]
    argv += ["--val-every", "2", "--episodes", "3", "--configs", str(REPO / "configs")]
    assert cell_module.main(argv) == 1
    assert "1 of 3 episodes erred" in capsys.readouterr().err
    assert not Path("results").exists()
    monkeypatch.setattr(cell_module, "evaluate_checkpoints", fake_test)
    assert cell_module.main(argv) == 0
    assert len(fakes.calls) == 1  # the finished fit was kept, only the test ran again
    assert Path("results/block-insertion/mira.json").is_file()


def test_a_cell_records_the_strict_check_beside_the_success_rate(fakes, monkeypatch):
    def judged_test(run_dir, split, episodes, *, only, **kwargs):
        """fake_test's episodes, the first of them alone passing the strict 6-DoF check."""
        records = fake_test(run_dir, split, episodes, only=only, **kwargs)
        for record in records:
            for index, result in enumerate(record["episode_results"]):
                result["strict_success"] = index == 0
            record |= summarize(record["episode_results"])
        return records

    monkeypatch.setattr(cell_module, "evaluate_checkpoints", judged_test)
    _, stored = run()
    assert (stored["successes"], stored["strict_successes"], stored["episodes"]) == (2, 1, 3)
    assert stored["strict_success_rate"] == pytest.approx(1 / 3)
    assert stored["strict_ci_low"] < 1 / 3 < stored["strict_ci_high"]
    assert [r["strict_success"] for r in stored["episode_results"]] == [True, False, False]


def test_a_cell_of_records_without_the_strict_check_says_so_rather_than_zero(fakes):
    _, stored = run()  # fake_test's records predate the strict check
    strict = ("strict_successes", "strict_success_rate", "strict_ci_low", "strict_ci_high")
    assert [stored[key] for key in strict] == [None] * 4
    assert [r["strict_success"] for r in stored["episode_results"]] == [None] * 3


def test_a_cell_of_another_world_or_with_wrong_numbers_is_not_taken_for_measured(fakes):
    path, _ = run()
    stored = json.loads(path.read_text())
    path.write_text(json.dumps(stored | {"world": "deadbeefdeadbeef"}))
    world = f"measured in world deadbeefdeadbeef.*, this checkout's world is {world_fingerprint()}"
    with pytest.raises(CellError, match=world):
        run()
    path.write_text(json.dumps(stored | {"successes": 3}))
    with pytest.raises(CellError, match="not the 95% Wilson interval of 3 of 3.*--force replaces"):
        run()
    assert len(fakes.calls) == 1


CELL_ARGV = ["--task", "block-insertion", "--method", "mira", "--imagery", "oracle"]
CELL_ARGV += ["--steps", "8", "--val-every", "2", "--val-episodes", "4", "--episodes", "3"]
CELL_ARGV += ["--configs", str(REPO / "configs"), "--device", "cpu"]


def test_a_second_run_cell_of_the_same_cell_exits_naming_the_first(fakes, monkeypatch, capsys):
    second = []

    def fit_while_another_starts(args):
        if not second:  # the first fit: the same command starts again, as from another shell
            second.append(None)
            second[0] = cell_module.main(CELL_ARGV)
        return fakes(args)

    monkeypatch.setattr(cell_module, "build_cli", fit_while_another_starts)
    assert cell_module.main(CELL_ARGV) == 0
    assert second == [2] and len(fakes.calls) == 1
    err = capsys.readouterr().err
    assert f"this cell is being measured by run-cell, pid {os.getpid()}" in err
    assert cell_module.main(CELL_ARGV) == 0 and "skipped" in capsys.readouterr().out


def test_a_moved_run_folder_with_a_lagging_last_checkpoint_is_not_fitted_again(fakes):
    """As Lightning leaves a fit resumed in a moved folder: `last.ckpt` at an earlier step, the
    later steps' copy in `last-v1.ckpt`."""
    run_dir, _ = run(fit_only=True)
    moved = Path("moved/logs")
    moved.parent.mkdir()
    Path("logs").rename(moved)
    checkpoints = moved.joinpath(*run_dir.parts[1:], "checkpoints")
    (checkpoints / "last.ckpt").write_bytes((checkpoints / "step000004.ckpt").read_bytes())
    (checkpoints / "last-v1.ckpt").write_bytes((checkpoints / "step000006.ckpt").read_bytes())
    _, stored = run(logs=moved / "cells")
    assert len(fakes.calls) == 1  # the finished fit is not trained again
    assert stored["checkpoint"]["path"] == str(checkpoints / "step000006.ckpt")


def test_a_partly_written_checkpoint_is_skipped_on_resume(fakes, caplog):
    fakes.interrupt_at = 6
    with pytest.raises(KeyboardInterrupt):
        run()
    (checkpoints,) = Path("logs/cells").rglob("checkpoints")
    for name in ("last.ckpt", "step000006.ckpt"):  # a full disk cut them short
        (checkpoints / name).write_bytes((checkpoints / name).read_bytes()[:100])
    fakes.interrupt_at = None
    _, stored = run()
    assert fakes.calls[-1] == str(checkpoints / "step000004.ckpt")
    assert "skipping unreadable checkpoint" in caplog.text and stored["checkpoint"]["step"] == 6


def test_unwritable_folders_and_a_bad_lr_are_named_before_anything_runs(fakes):
    Path("file").write_text("a file where a folder should be")
    with pytest.raises(CellError, match=r"results folder file/block-insertion cannot be written"):
        run(results=Path("file"))
    with pytest.raises(CellError, match=r"fit runs folder file/cells/.* is not a folder"):
        run(logs=Path("file/cells"))
    Path("data").write_text("no folder: the imagery cache data/imagery-cache cannot be made")
    with pytest.raises(CellError, match="the imagery cache folder data/imagery-cache cannot be"):
        run()
    Path("data").unlink()
    for lr in (float("nan"), float("inf"), -1e-3):
        with pytest.raises(CellError, match=f"lr must be > 0 and finite, got {lr}"):
            run(lr=lr)
    assert fakes.calls == [] and not Path("logs").exists()


@pytest.mark.parametrize(
    ("measured_under", "taken"),
    [
        ({}, True),
        # an imagery candidate's test, or one under another view choice, is not the cell's
        ({"imagery_options": {"iterations": 20}}, False),
        ({"test_time_options": {"view_choice": "view_softmax"}}, False),
    ],
)
def test_a_finished_test_is_taken_again_when_only_the_cell_write_failed(
    fakes, monkeypatch, measured_under, taken
):
    tested, write_json = [], cell_module.write_json

    def test_recorded(run_dir, split, episodes, *, only, **kwargs):
        """fake_test, its test records written to the run's evaluation/ as the real one does."""
        records = fake_test(run_dir, split, episodes, only=only, **kwargs)
        for record in records if split == "test" else []:
            tested.append(record["checkpoint"])
            record |= {"method": "mira", "task": "block-insertion", "imagery": "oracle"}
            record |= {"wall_s": 5.0} | measured_under
            write_new_json(run_dir / "evaluation", f"{only[0].stem}-test-normal", record)
        return records

    def full_disk(path, payload, **options):
        if Path(path).parent == Path("results/block-insertion"):
            raise OSError(28, "No space left on device")
        return write_json(path, payload, **options)

    monkeypatch.setattr(cell_module, "evaluate_checkpoints", test_recorded)
    monkeypatch.setattr(cell_module, "write_json", full_disk)
    with pytest.raises(CellError, match="No space left.*writes the cell without testing again"):
        run()
    monkeypatch.setattr(cell_module, "write_json", write_json)
    _, stored = run()
    assert len(tested) == (1 if taken else 2) and len(fakes.calls) == 1
    assert (stored["episodes"], stored["successes"]) == (3, 2)
    assert (stored["test_wall_s"] == 5.0) is taken  # the recorded test's time, or a new test's


def test_a_fresh_fit_failing_before_a_checkpoint_leaves_no_run_folder_nor_config_file(
    fakes, monkeypatch
):
    during = []

    def out_of_memory(args):
        during.extend(path.name for path in Path("logs").rglob("version_*/*"))
        raise RuntimeError("CUDA out of memory")

    monkeypatch.setattr(cell_module, "build_cli", out_of_memory)
    with pytest.raises(RuntimeError, match="out of memory"):
        run()
    assert during == [cell_module.SEGMENTS]  # the config goes to the fit as text, not a file
    assert not list(Path("logs").rglob("version_*"))


def committed_cells() -> list[Path]:
    """The run-cell cells of this checkout's world under results/ (sweeps included)."""
    paths = sorted((REPO / "results").rglob("*.json"))
    return [
        path
        for path in paths
        if "archive" not in path.relative_to(REPO).parts
        and "protocol" in json.loads(path.read_text())
    ]


def test_every_committed_cell_keeps_its_protocol_and_id():
    cells = committed_cells()
    table = [path for path in cells if "sweep" not in path.relative_to(REPO).parts]
    assert len(table) == 54  # the 48 cells of the table and 6 trained Challenging (and the sweeps')
    for path in cells:
        cell = load_cell(path)
        recomputed = cell_module.stored_protocol(cell, METHODS[cell["method"]].input_kind)
        assert (recomputed, cell_module.protocol_id(recomputed)) == (
            cell["protocol"],
            cell["protocol_id"],
        ), path


def test_every_committed_cell_is_measured_under_the_command_it_was_run_with(fakes, monkeypatch):
    """Its options and overlays as the results page's commands give them (`run_cell_command`: a
    NeRF cell of the reference imagery with the overlay that takes it back), the configs resolved
    for real."""
    monkeypatch.setattr(cell_module, "resolve_config", real_config)
    for path in committed_cells():
        cell = json.loads(path.read_text())
        protocol = cell["protocol"]
        options = dict(
            task=protocol["task"],
            method=protocol["method"],
            setting=protocol.get("trained_setting", protocol["setting"]),
            test_setting=protocol["setting"],
            imagery=protocol["imagery"],
            steps=protocol["steps"],
            batch_size=protocol["batch_size"],
            lr=protocol["lr"],
            episodes=protocol["test_episodes"],
            val_every=protocol["validation_every"],
            val_episodes=protocol["validation_episodes"],
            overlays=[REPO / overlay for overlay in re.findall(r"--config (\S+)", command(cell))],
            config_dir=REPO / "configs",
            results=path.parent.parent,
        )
        assert run_cell(**options) == (path, None), path
    assert fakes.calls == []


TRAINING_OVERLAYS = {
    "trainer.accumulate_grad_batches": ("trainer: {accumulate_grad_batches: 2}", 2),
    "trainer.gradient_clip_val": ("trainer: {gradient_clip_val: 0.5}", 0.5),
    "seed_everything": ("seed_everything: 7", 7),
    "data.augment": ("data: {init_args: {augment: false}}", False),
    "data.negative_view_scale": ("data: {init_args: {negative_view_scale: null}}", None),
}


def test_an_overlay_changing_training_is_another_protocol_and_never_resumes_a_fit(
    fakes, monkeypatch
):
    monkeypatch.setattr(cell_module, "resolve_config", real_config)
    fakes.interrupt_at = 4
    with pytest.raises(KeyboardInterrupt):
        run()
    fakes.interrupt_at = None
    clipped = Path("clip.yaml")
    clipped.write_text(TRAINING_OVERLAYS["trainer.gradient_clip_val"][0])
    # not the interrupted fit without the clip: a fit of its own
    _, record = run(overlays=[clipped], results=Path("clipped"))
    assert fakes.calls == [None, None] and record["protocol"]["training"] == {
        "trainer.gradient_clip_val": 0.5
    }
    unclipped = Path(run()[1]["run_dir"])  # the interrupted fit, resumed
    assert fakes.calls[-1] == str(unclipped / "checkpoints" / "step000004.ckpt")
    assert Path(record["run_dir"]).parent != unclipped.parent
    for key, (text, value) in TRAINING_OVERLAYS.items():
        overlay = Path(f"{key}.yaml")
        overlay.write_text(text)
        with pytest.raises(
            CellError, match=re.escape(f"training None there, {{'{key}': {value}}}")
        ):
            run(overlays=[overlay])  # not "the same protocol: skipped"
    assert len(fakes.calls) == 3


def merged(config: dict, overlay: dict) -> dict:
    """`config` with the settings of `overlay` in place (dicts merged key by key)."""
    both = {**config}
    for key, value in overlay.items():
        both[key] = merged(config.get(key, {}), value) if isinstance(value, dict) else value
    return both


def test_the_gpu_overlays_leave_the_protocol_but_mixed_precision_is_another():
    """Where and how fast a fit runs is no part of its protocol (a `--fit-only` fit on a GPU
    machine is found by the same command without the overlay); its arithmetic is. (The overlays
    are merged into the resolved config here: it is resolved where no GPU is.)"""
    files = cell_module.config_files(REPO / "configs", "block-insertion", "normal", "mira")
    config = real_config(files)

    def protocol(*overlays: str) -> dict:
        overlaid = config
        for name in overlays:
            overlay = yaml.safe_load((REPO / "configs" / "gpu" / f"{name}.yaml").read_text())
            overlaid = merged(overlaid, overlay)
        return cell_module.cell_protocol(overlaid, "mira", "imagery")

    assert protocol("h100") == protocol("shared", "cuda_graphs") == protocol()
    assert protocol("h100", "bf16") == protocol() | {
        "training": {"trainer.precision": "bf16-mixed"}
    }


def test_a_run_fitted_under_other_settings_is_neither_resumed_nor_tested(fakes, capsys):
    """As an earlier run-cell, whose protocol left gradient clipping out, left its fit in the
    folder of the protocol without it."""
    fakes.interrupt_at = 4
    with pytest.raises(KeyboardInterrupt):
        run()
    (saved,) = Path("logs/cells").rglob("config.yaml")
    config = yaml.safe_load(saved.read_text())
    config["trainer"]["gradient_clip_val"] = 0.5
    saved.write_text(yaml.safe_dump(config))
    assert cell_module.main(CELL_ARGV) == 2
    err = capsys.readouterr().err
    assert f"{saved.parent} was fitted under other settings (trainer.gradient_clip_val 0.5 " in err
    assert "there, None here; " in err and len(fakes.calls) == 1
    fakes.interrupt_at = None
    _, record = run(force=True)  # a fresh fit
    assert fakes.calls[-1] is None and record["run_dir"] != str(saved.parent)


def test_colour_augmentation_is_a_protocol_of_its_own_and_its_absence_changes_no_id():
    protocol = cell_module.cell_protocol(CONFIG, "mira", "imagery")
    data = CONFIG["data"] | {"init_args": CONFIG["data"]["init_args"] | {"colour_augment": False}}
    assert cell_module.cell_protocol(CONFIG | {"data": data}, "mira", "imagery") == protocol
    data["init_args"]["colour_augment"] = True
    recoloured = cell_module.cell_protocol(CONFIG | {"data": data}, "mira", "imagery")
    assert recoloured == protocol | {"colour_augment": True}
    assert cell_module.protocol_id(recoloured) != cell_module.protocol_id(protocol)


def test_square_attention_is_a_protocol_of_its_own_and_its_absence_changes_no_id():
    """MIRA's square attention input (configs/recipe/square_attention.yaml): every committed cell
    was fitted without it, so off it names nothing, on it is another protocol."""
    files = cell_module.config_files(REPO / "configs", "hanging-disks", "normal", "transporter_se2")
    plain = real_config(files)
    squared = real_config([*files, REPO / "configs" / "recipe" / "square_attention.yaml"])
    protocol = cell_module.cell_protocol(plain, "transporter_se2", "heightmap")
    assert "square_attention" not in json.dumps(protocol)
    assert cell_module.cell_protocol(squared, "transporter_se2", "heightmap") == protocol | {
        "square_attention": True
    }


def test_nerf_imagery_settings_other_than_the_reference_are_a_protocol_of_their_own(
    fakes, monkeypatch
):
    """An imagery overlay and a changed default of the imagery's settings alike: a cell records
    the imagery it was measured on, so a cell of the reference imagery stays what it was."""
    monkeypatch.setattr(cell_module, "resolve_config", real_config)
    reference = [REPO / "configs" / "imagery" / "reference.yaml"]
    path, record = run(imagery="nerf", overlays=reference)
    assert "imagery_changes" not in record["protocol"]
    default = cell_module.cell_protocol(
        real_config(
            cell_module.config_files(REPO / "configs", "block-insertion", "normal", "mira")
        ),
        "mira",
        "imagery",
    )
    assert default["imagery_changes"] == {"colour_init": "table", "sparsity_weight": 0.0003}
    assert "training" not in default  # named once, as imagery
    changes = "imagery_changes None there, {'sparsity_weight': 0.0003, 'colour_init': 'table'}"
    with pytest.raises(CellError, match=re.escape(changes)):
        run(imagery="nerf")  # the default imagery: not the reference cell's protocol
    # the code's default iterations (400) no longer the reference's: every NeRF fit is another
    monkeypatch.setitem(observation.REFERENCE_IMAGERY, "iterations", 300)
    assert cell_module.stored_protocol(load_cell(path), "imagery") == record["protocol"]
    with pytest.raises(
        CellError, match=re.escape("imagery_changes None there, {'iterations': 400} here")
    ):
        run(imagery="nerf", overlays=reference)
    assert "imagery_changes" not in cell_module.cell_protocol(
        record["config"]
        | {"data": {"init_args": record["config"]["data"]["init_args"] | {"imagery": "oracle"}}},
        "mira",
        "imagery",
    )


def test_train_time_counts_an_interrupted_segment_up_to_its_own_last_checkpoint(tmp_path):
    """Killed at t=1000 after a checkpoint at t=700, resumed at t=2000 and done in 500 s (its own
    checkpoints written at t=2400 and t=2500): 700 + 500 s, not until the resumed fit's last."""
    (tmp_path / "checkpoints").mkdir()
    for name, mtime in [("step500", 400), ("step1000", 700), ("step1500", 2400), ("last", 2500)]:
        checkpoint = tmp_path / "checkpoints" / f"{name}.ckpt"
        checkpoint.touch()
        os.utime(checkpoint, (mtime, mtime))
    segments = [{"start_time": 0, "wall_s": None}, {"start_time": 2000, "wall_s": 500}]
    (tmp_path / cell_module.SEGMENTS).write_text(json.dumps(segments))
    assert cell_module.train_wall_s(tmp_path) == 1200
    segments.append({"start_time": 3000, "wall_s": None})  # interrupted before its first checkpoint
    (tmp_path / cell_module.SEGMENTS).write_text(json.dumps(segments))
    assert cell_module.train_wall_s(tmp_path) == 1200


def test_budget_options_are_checked(fakes, capsys):
    with pytest.raises(CellError, match="not a multiple of the validation interval 1000"):
        apply_budget(CONFIG, steps=2500)
    config = apply_budget(CONFIG, steps=3000, batch_size=4, lr=1e-3, val_every=500)
    assert config["trainer"]["callbacks"][1]["init_args"]["every_n_train_steps"] == 500
    assert (config["data"]["init_args"]["batch_size"], config["model"]["init_args"]["lr"]) == (
        4,
        1e-3,
    )
    assert CONFIG["trainer"]["max_steps"] == 40000  # the input is left alone
    without = {**CONFIG, "trainer": {"max_steps": 10, "callbacks": []}}
    with pytest.raises(CellError, match="0 SuccessRateCallback callbacks"):
        apply_budget(without)
    with pytest.raises(CellError, match="batch_size must be > 0"):
        apply_budget(CONFIG, batch_size=0)
    argv = ["--task", "block-insertion", "--method", "form2fit", "--imagery", "oracle"]
    assert cell_module.main(argv + ["--configs", str(REPO / "configs")]) == 2
    assert "--imagery applies to methods that read imagery" in capsys.readouterr().err
    assert (
        cell_module.main(["--task", "hanging-disks", "--method", "mira", "--setting", "flat"]) == 2
    )
    assert "no config configs/hanging_disks_flat.yaml" in capsys.readouterr().err


@pytest.mark.slow
def test_a_tiny_cell_end_to_end(tmp_path):
    """mira with oracle imagery at 6.25 cm pixels: 2 demonstrations, 4 steps, 2 validation and 2
    test episodes, data generated on the way; then the same command skips the cell."""
    overlay = tmp_path / "tiny.yaml"
    overlay.write_text(
        """trainer: {accelerator: cpu, devices: 1, enable_progress_bar: false, log_every_n_steps: 1}
model:
  init_args: {pixel_size: 0.0625, n_rotations: 4, crop_size: 8, width: 8}
data:
  init_args: {n_demos: 2, pixel_size: 0.0625, n_rotations: 4, samples_per_epoch: 4}
"""
    )
    argv = [sys.executable, "-m", "nerf_transporter.cli", "run-cell", "--task", "block-insertion"]
    argv += ["--method", "mira", "--imagery", "oracle", "--steps", "4", "--val-every", "2"]
    argv += ["--val-episodes", "2", "--episodes", "2", "--eval-workers", "1"]
    argv += ["--config", str(overlay), "--configs", str(REPO / "configs")]
    env = {**os.environ, "PYTHONPATH": str(REPO / "src"), "OMP_NUM_THREADS": "1"}
    result = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-3000:]
    cell = json.loads((tmp_path / "results/block-insertion/mira-oracle.json").read_text())
    assert (cell["episodes"] + cell["errors"], cell["test_seeds"]) == (2, [1, 3])
    rounds = cell["validation"]
    assert [r["step"] for r in rounds] == [2, 4] and cell["checkpoint"]["validation_episodes"] == 2
    best = max(rounds, key=lambda r: (r["success_rate"] is not None, r["success_rate"], r["step"]))
    assert cell["checkpoint"]["step"] == best["step"]  # the best round; of equals the later
    assert cell["imagery"] == "oracle" and cell["protocol"]["pixel_size"] == 0.0625
    assert cell["overlays"] == [str(overlay)]
    assert Path(tmp_path, cell["checkpoint"]["path"]).is_file()
    # the config Lightning saved in the run names the settings the cell's protocol does
    assert cell["protocol"]["training"] == {"data.samples_per_epoch": 4}
    cell_module.check_fitted_as(Path(tmp_path, cell["run_dir"]), cell["config"])
    again = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert again.returncode == 0 and "skipped" in again.stdout
