import functools
import http.server
import json
import logging
import os
import re
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace

import imageio.v2 as imageio
import lightning.pytorch as pl
import numpy as np
import pytest
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from torch.utils.data import DataLoader

from nerf_transporter.cli import lightning_main, main
from nerf_transporter.evaluation.callback import SuccessRateCallback
from nerf_transporter.experiments.lightning_cli import build_cli, fit_summary
from nerf_transporter.experiments.runs import claim_version, latest_checkpoint
from nerf_transporter.methods import METHODS, Mira, TransporterSE2
from tests.helpers.synthetic import SIZE, STATE_DIM, synthetic_batch, synthetic_observation

REPO = Path(__file__).resolve().parents[1]
TASK_CONFIGS = sorted((REPO / "configs").glob("*.yaml")) + sorted(
    (REPO / "configs" / "quick").glob("*.yaml")
)


class SyntheticDataModule(pl.LightningDataModule):
    """A few random samples shaped for the model's `input_kind` (docs/interfaces.md)."""

    def __init__(
        self,
        task: str = "block-insertion",
        setting: str = "normal",
        batch_size: int = 2,
        n_samples: int = 4,
    ) -> None:
        super().__init__()
        self.task, self.setting = task, setting
        self.batch_size, self.n_samples = batch_size, n_samples
        self.pixel_size, self.n_rotations = SIZE["pixel_size"], SIZE["n_rotations"]
        self.state_dim = STATE_DIM

    def setup(self, stage: str) -> None:
        batch = synthetic_batch(self.trainer.lightning_module.input_kind, self.n_samples)
        self.samples = [{k: v[i] for k, v in batch.items()} for i in range(self.n_samples)]

    def train_dataloader(self) -> DataLoader:
        return DataLoader(self.samples, batch_size=self.batch_size)

    def val_dataloader(self) -> list:
        return []  # as RavensDataModule without validation demos (data.n_val_demos: 0)


def tiny_config(path: Path, **data_args) -> Path:
    model_args = ", ".join(f"{k}: {v}" for k, v in SIZE.items())
    data_args = ", ".join(f"{k}: {v}" for k, v in data_args.items())
    path.write_text(
        f"""seed_everything: 0
trainer:
  max_steps: 2
  accelerator: cpu
  devices: 1
  log_every_n_steps: 1
  enable_progress_bar: false
  enable_model_summary: false
model:
  class_path: Mira
  init_args: {{{model_args}, log_images_every_n_steps: 1}}
data:
  class_path: tests.test_cli.SyntheticDataModule
  init_args: {{{data_args}}}
"""
    )
    return path


@pytest.fixture(autouse=True)
def in_tmp_dir(tmp_path, monkeypatch):
    """Run in a temporary folder (logs/ goes there), as `lightning` with one thread."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["lightning"])
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize("command", [["fit", "--help"]])
def test_fit_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        build_cli(command)
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "--model" in out and "--data" in out and "--trainer.max_steps" in out


def test_nerf_transporter_lists_and_runs_training_commands(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    commands = [line for line in out.splitlines() if line.startswith("  ")]
    assert {line.split()[0] for line in commands} >= {"fit", "test", "evaluate-checkpoints"}
    # descriptions start in one column, after the longest command name
    assert len({len(line) - len(line[2:].split(maxsplit=1)[1]) for line in commands}) == 1
    with pytest.raises(SystemExit) as exit_info:
        main(["fit", "--help"])
    assert exit_info.value.code == 0


def test_misspelt_key_gives_a_clear_error(tmp_path, capsys):
    config = tiny_config(tmp_path / "tiny.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("model:\n  class_path: Mira\n  init_args:\n    widht: 8\n")
    with pytest.raises(SystemExit) as exit_info:
        build_cli(["fit", "--config", str(config), "--config", str(bad)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "widht" in err and "not accepted" in err


@pytest.mark.parametrize("config", TASK_CONFIGS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_task_configs_build_mira_and_switch_method(config):
    cli = build_cli(["--config", str(config)], run=False)
    assert isinstance(cli.model, Mira)
    # the closed-loop test callback joins the callbacks the config lists
    assert [type(c).__name__ for c in cli.trainer.callbacks].count("SuccessRateCallback") == 1
    assert [c for c in cli.trainer.callbacks if c is cli.closed_loop_test]
    assert cli.model.pixel_size == cli.datamodule.pixel_size
    assert cli.model.n_rotations == cli.datamodule.n_rotations
    assert cli.trainer.max_steps > 0
    switched = build_cli(
        ["--config", str(config), "--config", str(REPO / "configs/model/transporter_se2.yaml")],
        run=False,
    )
    assert type(switched.model) is TransporterSE2
    assert switched.model.hparams["width"] == cli.model.hparams["width"]
    assert switched.model.lr == cli.model.lr
    log_dir = Path(switched.trainer.logger.log_dir)
    task = cli.datamodule.task + ("" if cli.datamodule.setting == "normal" else "-challenging")
    assert log_dir.parent == Path("logs") / task / "transporter_se2"


def test_paper_iteration_counts():
    steps = {
        "block_insertion": 40000,
        "place_red_in_green": 24000,
        "hanging_disks": 9000,
        "stacking_kits": 20000,
        "place_red_in_green_challenging": 40000,
    }
    for name, count in steps.items():
        cli = build_cli(["--config", str(REPO / f"configs/{name}.yaml")], run=False)
        assert cli.trainer.max_steps == count
        assert cli.datamodule.n_demos == 10


@pytest.mark.parametrize("name", list(METHODS))
def test_two_step_fit_logs_and_checkpoints(name, tmp_path):
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=2)
    cli = build_cli(
        ["fit", "--config", str(config), "--config", str(REPO / f"configs/model/{name}.yaml")]
    )
    assert cli.trainer.global_step == 2
    run_dir = tmp_path / "logs" / "block-insertion" / name / "version_0"
    events = list(run_dir.glob("events.out.tfevents.*"))
    assert events, f"no TensorBoard events in {run_dir}"
    checkpoints = list((run_dir / "checkpoints").glob("*.ckpt"))
    assert len(checkpoints) == 1
    checkpoint = torch.load(checkpoints[0], weights_only=True)
    hparams = {k: v for k, v in checkpoint["hyper_parameters"].items() if not k.startswith("_")}
    reloaded = METHODS[name](**hparams)
    reloaded.load_state_dict(checkpoint["state_dict"])
    observation = synthetic_observation(reloaded.input_kind)
    expected, actual = cli.model.act(observation), reloaded.act(observation)
    for key in ("pick", "place"):
        for a, b in zip(expected[key], actual[key], strict=True):
            np.testing.assert_array_equal(a, b)
    if reloaded.input_kind != "state":
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

        accumulator = EventAccumulator(str(run_dir))
        accumulator.Reload()
        assert {"heatmap/pick", "heatmap/place"} <= set(accumulator.Tags()["images"])
        assert "train/loss" in accumulator.Tags()["scalars"]


@pytest.mark.parametrize("name", ["transporter_se2", "mira"])
def test_a_fit_is_a_function_of_its_seed(name, tmp_path):
    """Two fits of one config on one machine end with equal weights, bit for bit."""
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=2)
    model = str(REPO / f"configs/model/{name}.yaml")
    first, second = (
        build_cli(["fit", "--config", str(config), "--config", model]).model.state_dict()
        for _ in range(2)
    )
    assert first.keys() == second.keys()
    for key in first:
        torch.testing.assert_close(first[key], second[key], rtol=0, atol=0, msg=key)


def test_ddp_two_cpu_processes(tmp_path):
    """Lightning's own DDP on two CPU processes (~15 s: two interpreters start)."""
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=1)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "src")])}
    result = subprocess.run(
        [sys.executable, "-m", "nerf_transporter.cli", "fit", "--config", str(config)]
        + ["--trainer.strategy", "ddp", "--trainer.devices", "2", "--trainer.accelerator", "cpu"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    run_dir = tmp_path / "logs" / "block-insertion" / "mira" / "version_0"
    assert list((run_dir / "checkpoints").glob("*.ckpt"))


def test_runs_started_together_claim_distinct_folders(tmp_path):
    runs = tmp_path / "logs" / "block-insertion" / "mira"
    start = threading.Barrier(8)

    def claim(_):
        start.wait()
        return claim_version(runs)

    with ThreadPoolExecutor(8) as pool:
        versions = list(pool.map(claim, range(8)))
    assert sorted(versions) == list(range(8))


def fit_two_steps(tmp_path) -> Path:
    """A 2-step tiny mira run; returns its folder (logs/block-insertion/mira/version_0)."""
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=2)
    build_cli(["fit", "--config", str(config)])
    return tmp_path / "logs" / "block-insertion" / "mira" / "version_0"


def test_ckpt_path_last_resumes_the_latest_run_in_its_folder(tmp_path):
    run = fit_two_steps(tmp_path)
    config_text = (run / "config.yaml").read_text()
    config = tmp_path / "tiny.yaml"
    cli = build_cli(
        ["fit", "--config", str(config), "--trainer.max_steps", "4", "--ckpt_path", "last"]
    )
    assert cli.trainer.global_step == 4  # continued from step 2
    assert Path(cli.trainer.log_dir) == Path("logs/block-insertion/mira/version_0")
    assert not run.with_name("version_1").exists()
    # the run's config stays; the resumed one is saved beside it
    assert (run / "config.yaml").read_text() == config_text
    assert "max_steps: 4" in (run / "config-fit.yaml").read_text()


def test_resume_takes_the_furthest_checkpoint_of_a_run_copied_with_one_time(tmp_path):
    folder = tmp_path / "runs" / "version_0" / "checkpoints"
    folder.mkdir(parents=True)
    for step in (1500, 500, 2000, 1000):  # written in no order, then stamped alike (tar, rsync)
        path = folder / f"step{step:06d}.ckpt"
        torch.save({"global_step": step}, path)
        os.utime(path, (1.0e9, 1.0e9))
    assert latest_checkpoint(tmp_path / "runs") == folder / "step002000.ckpt"
    torch.save({"global_step": 1700}, folder / "last.ckpt")  # behind: its name does not win
    assert latest_checkpoint(tmp_path / "runs") == folder / "step002000.ckpt"
    torch.save({"global_step": 2100}, folder / "last.ckpt")
    assert latest_checkpoint(tmp_path / "runs") == folder / "last.ckpt"


def test_resume_skips_a_partly_written_checkpoint_with_a_warning(tmp_path, caplog):
    folder = tmp_path / "runs" / "version_0" / "checkpoints"
    folder.mkdir(parents=True)
    torch.save({"global_step": 2}, folder / "step000002.ckpt")
    for name in ("step000003.ckpt", "last.ckpt"):  # cut short by a full disk
        (folder / name).write_bytes(b"PK\x03\x04 cut short")
    later = tmp_path / "runs" / "version_1" / "checkpoints"
    later.mkdir(parents=True)
    (later / "last.ckpt").write_bytes(b"")  # a later run with nothing readable
    with caplog.at_level(logging.WARNING):
        assert latest_checkpoint(tmp_path / "runs") == folder / "step000002.ckpt"
    assert (
        "skipping unreadable checkpoint" in caplog.text and str(folder / "last.ckpt") in caplog.text
    )


@pytest.mark.parametrize(
    ("argv", "problem"),
    [
        (["test", "--ckpt_path", "a-folder"], "--ckpt_path a-folder is a folder, not a checkpoint"),
        (["test", "--ckpt_path", "missing.ckpt"], "--ckpt_path missing.ckpt: no such checkpoint"),
        (["test", "--ckpt_path", "cut.ckpt"], "--ckpt_path cut.ckpt is not a readable checkpoint"),
        (
            ["test", "--ckpt_path", "step2.ckpt", "--data.init_args.test_episodes", "0"],
            "test_episodes 0: a test needs at least one episode",
        ),
        (
            ["test", "--ckpt_path", "step2.ckpt", "--video", "a-file/videos"],
            "--video a-file/videos cannot be written",
        ),
        (["fit", "--trainer.max_steps", "-5"], "max_steps -5: a fit needs at least one training"),
        (["fit", "--trainer.max_steps", "0"], "max_steps 0: a fit needs at least one training"),
    ],
    ids=["folder", "missing", "truncated", "no-episodes", "video-unwritable", "steps-5", "steps0"],
)
def test_lightning_names_an_option_it_cannot_run_and_claims_no_run_folder(
    tmp_path, capsys, argv, problem
):
    Path("a-folder").mkdir()
    Path("a-file").write_text("a file where a folder should be")
    Path("cut.ckpt").write_bytes(b"PK\x03\x04 cut short")
    torch.save({"global_step": 2}, "step2.ckpt")
    config = closed_loop_test_config(tmp_path)
    assert lightning_main([argv[0], "--config", str(config), *argv[1:]]) == 2
    assert problem in capsys.readouterr().err
    assert not list(Path("logs").rglob("version_*"))


def test_a_fit_that_fails_before_training_leaves_no_run_folder(tmp_path):
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=0)  # its DataLoader refuses it
    with pytest.raises(ValueError, match="batch_size"):
        lightning_main(["fit", "--config", str(config)])
    assert not list(Path("logs").rglob("version_*"))


def test_ckpt_path_last_without_a_run_is_a_named_error(tmp_path, capsys):
    config = tiny_config(tmp_path / "tiny.yaml")
    assert lightning_main(["fit", "--config", str(config), "--ckpt_path", "last"]) == 2
    assert "no earlier run to resume" in capsys.readouterr().err
    assert not list(Path("logs").rglob("events.out.tfevents.*"))


def closed_loop_test_config(tmp_path) -> Path:
    """The tiny mira on 2 block-insertion test episodes with oracle imagery, in this process."""
    data_args = {**SIZE, "task": "block-insertion", "imagery": "oracle", "test_episodes": 2}
    data_args.pop("crop_size"), data_args.pop("width")
    config = tmp_path / "test.yaml"
    config.write_text(
        f"""trainer: {{accelerator: cpu, devices: 1, enable_progress_bar: false}}
model: {{class_path: Mira, init_args: {SIZE}}}
data:
  class_path: nerf_transporter.data.datamodule.RavensDataModule
  init_args: {{{", ".join(f"{k}: {v}" for k, v in data_args.items())}, test_workers: 1}}
"""
    )
    return config


def test_lightning_test_video_writes_a_captioned_mp4_per_episode(tmp_path, capsys):
    run = fit_two_steps(tmp_path)
    (checkpoint,) = (run / "checkpoints").glob("*.ckpt")
    config = closed_loop_test_config(tmp_path)
    argv = ["test", "--config", str(config), "--ckpt_path", str(checkpoint), "--video", "videos"]
    capsys.readouterr()
    assert lightning_main(argv) == 0
    out, err = capsys.readouterr()
    # the rate is printed once, rounded, with its interval (not Lightning's float32 table)
    assert re.search(r"^test success: \d+% \(2, \d+-\d+\) - \d of 2$", out, re.M), out
    assert "Test metric" not in out
    # no terminal here, as in a log: the episodes' progress in lines
    assert "\r" not in err and re.search(r"^test episodes: 2/2 episodes  successes \d", err, re.M)
    videos = sorted(Path("videos").glob("*.mp4"))
    assert [v.name for v in videos] == [
        "block-insertion-normal-seed1-mira.mp4",
        "block-insertion-normal-seed3-mira.mp4",
    ]
    for video, seed in zip(videos, (1, 3), strict=True):
        reader = imageio.get_reader(video)
        frames = [frame for frame in reader]
        assert len(frames) > 30 and frames[0].ndim == 3  # plays: decoded frame by frame
        sidecar = json.loads(video.with_suffix(".json").read_text())
        assert sidecar["caption"][:2] == [f"block-insertion (normal), seed {seed}", "method: mira"]
        assert sidecar["outcome"] == ("success" if sidecar["success"] else "failure")
        assert sidecar["frames"] == len(frames)
        if sidecar["success"]:
            assert sidecar["caption"][2] == "success"
        else:  # the reason, with the pose error where the object missed its target
            assert sidecar["caption"][2].startswith(("the object did not end", sidecar["failure"]))


def test_lightning_test_with_erred_episodes_exits_non_zero_and_logs_into_the_run(tmp_path, capsys):
    run = fit_two_steps(tmp_path)
    (checkpoint,) = (run / "checkpoints").glob("*.ckpt")
    Path("data").mkdir()
    Path("data/imagery-cache").write_text("a file where the imagery cache folder should be")
    argv = [
        "test",
        "--config",
        str(closed_loop_test_config(tmp_path)),
        "--ckpt_path",
        str(checkpoint),
    ]
    assert lightning_main(argv) == 1
    err = capsys.readouterr().err
    assert "2 episodes erred (seeds 1, 3)" in err and "NotADirectoryError" in err
    results = json.loads((run / "checkpoints" / f"results-{checkpoint.stem}.json").read_text())
    assert (results["episodes"], results["errors"], results["erred_seeds"]) == (0, 2, [1, 3])
    assert [e["outcome"] for e in results["episode_results"]] == ["error", "error"]
    # logged into the checkpoint's run, not a new version; the fit's config is kept
    assert sorted(path.name for path in run.parent.iterdir()) == ["version_0"]
    assert (run / "config-test.yaml").is_file()
    assert "Synthetic" in (run / "config.yaml").read_text()


class Exploit:
    """Unpickling this runs code (it would create the file `exploited`)."""

    def __reduce__(self):
        return (Path.touch, (Path.cwd() / "exploited",))


def test_a_pickled_payload_behind_a_url_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch-home"))
    served = tmp_path / "served"
    served.mkdir()
    torch.save({"state_dict": {}, "payload": Exploit()}, served / "evil.ckpt")
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(served))
    with http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        url = f"http://127.0.0.1:{server.server_address[1]}/evil.ckpt"
        config = tiny_config(tmp_path / "tiny.yaml")
        code = lightning_main(["test", "--config", str(config), "--ckpt_path", url])
        server.shutdown()
    assert code == 2
    assert "refused to load the checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "exploited").exists()


@pytest.mark.parametrize("config", TASK_CONFIGS[:5], ids=lambda p: p.stem)
def test_gpu_overlays_stack_on_task_and_method_configs(config):
    overlays = [
        REPO / "configs/gpu" / name
        for name in ("h100.yaml", "width64.yaml", "bf16.yaml", "no_pybullet.yaml")
    ]
    argv = ["--config", str(config), "--config", str(REPO / "configs/model/transporter_se3.yaml")]
    argv += [arg for overlay in overlays for arg in ("--config", str(overlay))]
    cli = build_cli([*argv, "--trainer.accelerator", "cpu"], run=False)  # no GPU here
    assert type(cli.model).__name__ == "TransporterSE3" and cli.model.hparams["width"] == 64
    assert (cli.datamodule.num_workers, cli.datamodule.pin_memory) == (8, True)
    assert cli.trainer.precision == "bf16-mixed"
    assert (
        cli.trainer.max_steps == build_cli(["--config", str(config)], run=False).trainer.max_steps
    )
    assert not [c for c in cli.trainer.callbacks if type(c).__name__ == "SuccessRateCallback"]
    names = [type(c).__name__ for c in cli.trainer.callbacks]
    assert names.count("ClosedLoopTestCallback") == 1  # `lightning test` still plays the seeds


def test_colour_augmentation_overlay_reaches_the_datamodule():
    argv = ["--config", str(REPO / "configs/hanging_disks.yaml")]
    assert not build_cli(argv, run=False).datamodule.colour_augment
    argv += ["--config", str(REPO / "configs/data/colour_augment.yaml")]
    assert build_cli(argv, run=False).datamodule.colour_augment


def test_gpu_machine_overlays_stack_on_the_state_method():
    """h100.yaml, bf16.yaml and no_pybullet.yaml set nothing GT-State MLP lacks (width is apart)."""
    argv = [
        "--config",
        str(TASK_CONFIGS[0]),
        "--config",
        str(REPO / "configs/model/gt_state_mlp.yaml"),
    ]
    for name in ("h100.yaml", "bf16.yaml", "no_pybullet.yaml"):
        argv += ["--config", str(REPO / "configs/gpu" / name)]
    cli = build_cli([*argv, "--trainer.accelerator", "cpu"], run=False)
    assert type(cli.model).__name__ == "GTStateMLP"
    assert (cli.datamodule.num_workers, cli.datamodule.pin_memory) == (8, True)


@pytest.mark.parametrize("name", list(METHODS))
def test_mixed_precision_fit(name, tmp_path):
    """The bf16 autocast path of configs/gpu/bf16.yaml, run on the CPU's autocast."""
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=2)
    cli = build_cli(
        ["fit", "--config", str(config), "--config", str(REPO / f"configs/model/{name}.yaml")]
        + ["--trainer.precision", "bf16-mixed"]
    )
    assert cli.trainer.global_step == 2
    assert torch.isfinite(cli.trainer.callback_metrics["train_loss"])


def test_fit_ends_with_the_run_folder_and_the_next_command_and_no_tips(
    tmp_path, capsys, caplog, recwarn
):
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=2)
    assert lightning_main(["fit", "--config", str(config)]) == 0
    shown = [w for w in recwarn if not issubclass(w.category, DeprecationWarning)]  # as python
    assert not shown, [str(w.message) for w in shown]
    out = capsys.readouterr().out
    run = Path("logs/block-insertion/mira/version_0")
    assert f"run folder: {run}" in out
    (checkpoint,) = (run / "checkpoints").glob("*.ckpt")
    assert f"next: lightning test --config {run / 'config.yaml'} --ckpt_path {checkpoint}" in out
    assert "Tip:" not in caplog.text


def test_fit_names_the_latest_of_the_best_validated_checkpoints(tmp_path):
    """As run-cell and evaluate-checkpoints choose; Lightning's best_model_path is the first."""
    folder = tmp_path / "run" / "checkpoints"
    folder.mkdir(parents=True)
    for step, score in ((2, 0.5), (4, float("-inf")), (6, 0.5), (8, 0.25)):  # -inf: erred round
        state = {"monitor": "eval/success_rate", "current_score": torch.tensor(score)}
        checkpoint = {"global_step": step, "callbacks": {"ModelCheckpoint{...}": state}}
        torch.save(checkpoint, folder / f"step{step:06d}.ckpt")
    checkpoints = ModelCheckpoint(dirpath=folder, monitor="eval/success_rate", mode="max")
    checkpoints.best_model_path = str(folder / "step000002.ckpt")
    trainer = SimpleNamespace(
        logger=SimpleNamespace(log_dir=str(tmp_path / "run")),
        checkpoint_callback=checkpoints,
        callbacks=[checkpoints, SuccessRateCallback(episodes=4)],
    )
    summary = fit_summary(trainer)
    best = folder / "step000006.ckpt"
    chosen = "validation success 2/4 at step 6, the latest of the best"
    assert f"best checkpoint ({chosen}): {best}" in summary
    assert f"--ckpt_path {best}" in summary


def test_a_fit_logged_to_a_file_reports_progress_in_lines(tmp_path, capsys):
    """stderr is no terminal here (as in a log file): plain lines, no carriage-return frames."""
    config = tiny_config(tmp_path / "tiny.yaml", batch_size=2)
    config.write_text(config.read_text().replace("  enable_progress_bar: false\n", ""))
    assert lightning_main(["fit", "--config", str(config)]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err
    (last,) = [line for line in err.splitlines() if line.startswith("step 2/2 ")]
    assert "train_loss" in last and last.endswith("steps/s")


def test_a_tool_whose_reader_left_stops_quietly(tmp_path):
    """`nerf-transporter report ... | head` ends without a traceback when head stops reading."""
    command = [sys.executable, "-m", "nerf_transporter.cli", "report", str(tmp_path)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)
    process.stdout.close()  # the reader is gone before the tool writes its table
    stderr = process.stderr.read().decode()
    assert process.wait(timeout=120) == 1
    assert "Traceback" not in stderr and "BrokenPipeError" not in stderr


QUICK_IMAGERY = {"voxel_size": 0.00625, "iterations": 300}  # configs/common/quick.yaml's


@pytest.mark.parametrize(
    ("recorded", "changes"),
    # what a checkpoint of the quick config saved before the default changed: its config's own
    [(QUICK_IMAGERY, {}), (None, {"colour_init": "table", "sparsity_weight": 0.0003})],
    ids=["written-before-the-default-changed", "written-since"],
)
def test_lightning_test_of_a_checkpoint_is_on_the_imagery_it_was_trained_on(
    tmp_path, monkeypatch, recorded, changes
):
    """As Lightning takes the model's hyper-parameters from `--ckpt_path`, the data's NeRF imagery
    is the checkpoint's (`RavensDataModule.trained_imagery`), not the config's defaults."""
    monkeypatch.chdir(tmp_path)
    # the data built, not tested: Trainer.test's arguments kept (the `test` sub-command's)
    monkeypatch.setattr(pl.Trainer, "test", functools.wraps(pl.Trainer.test)(lambda *a, **k: None))
    config = Path(__file__).resolve().parents[1] / "configs" / "quick" / "block_insertion.yaml"
    built = build_cli(["--config", str(config)], run=False)
    data = dict(built.datamodule.hparams)
    if recorded is not None:
        data["imagery_config"] = recorded
    checkpoint = tmp_path / "policy.ckpt"
    torch.save(
        {
            "pytorch-lightning_version": pl.__version__,
            "hyper_parameters": {k: v for k, v in built.model.hparams.items() if k[0] != "_"}
            | {"_class_path": built.model.hparams["_class_path"]},
            "datamodule_hyper_parameters": {k: v for k, v in data.items() if k != "_instantiator"},
            "state_dict": built.model.state_dict(),
        },
        checkpoint,
    )
    cli = build_cli(["test", "--config", str(config), "--ckpt_path", str(checkpoint)])
    scene = cli.datamodule.generation_config("train").scene
    assert scene.imagery_changes() == changes | QUICK_IMAGERY
