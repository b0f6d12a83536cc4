"""Bad input to the commands ends in one line naming the argument or file and the problem (exit
status 2), before any work is spent: no traceback, nothing written, no episode played."""

import json
import sys
from pathlib import Path

import gymnasium
import lightning.pytorch  # noqa: F401  (its log handler takes the session's stderr, not a test's)
import numpy as np
import pytest

import nerf_transporter  # noqa: F401  (registers the gymnasium ids)
from nerf_transporter.cli import lightning_main
from nerf_transporter.cli import main as cli_main
from nerf_transporter.data import episode as ep
from nerf_transporter.data import generate as gen
from nerf_transporter.evaluation.metrics import summarize
from nerf_transporter.evaluation.rollout import NOT_ACHIEVED
from nerf_transporter.experiments import failures
from nerf_transporter.sim.fingerprint import world_fingerprint
from nerf_transporter.sim.registration import env_id
from tests.data.test_generate import cli_args
from tests.helpers.fake_sim import PIXEL

REPO = Path(__file__).resolve().parents[1]
FIT = [
    "fit",
    "--config",
    str(REPO / "configs" / "quick" / "block_insertion.yaml"),
    "--config",
    str(REPO / "configs" / "model" / "gt_state_mlp.yaml"),
]
A_FILE = "a-file"  # a file where a folder should be


@pytest.fixture(autouse=True)
def in_tmp_dir(tmp_path, monkeypatch):
    """Run in a temporary folder holding `a-file`, as the `lightning` command."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["lightning"])
    Path(A_FILE).write_text("a file where a folder should be")


def one_line(err: str) -> str:
    """The single line of `err` (stderr of a refused command), besides Lightning's INFO lines."""
    lines = [line for line in err.strip().splitlines() if not line.startswith("INFO: ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (
            ["--data.init_args.task", "no-such-task"],
            "data.init_args of RavensDataModule: unknown task 'no-such-task'; valid tasks:",
        ),
        (
            ["--data.init_args.setting", "hard"],
            "data.init_args of RavensDataModule: unknown setting 'hard'; valid settings:",
        ),
        (["--data.init_args.pixel_size", "0"], "RavensDataModule: --pixel-size must be > 0"),
        (["--data.init_args.pixel_size", "-0.01"], "RavensDataModule: --pixel-size must be > 0"),
        (["--data.init_args.n_demos", "0"], "RavensDataModule: n_demos must be >= 1, got 0"),
        (["--data.init_args.n_demos", "-4"], "RavensDataModule: n_demos must be >= 1, got -4"),
        (["--model.init_args.lr", "-0.001"], "model.init_args of GTStateMLP: lr must be positive"),
        (["--data.init_args.batch_size", "0"], "RavensDataModule: batch_size must be >= 1, got 0"),
        (["--data.init_args.n_rotations", "0"], "n_rotations must be >= 1, got 0"),
    ],
    ids=["task", "setting", "pixel0", "pixel-", "demos0", "demos-", "lr-", "batch0", "rotations0"],
)
def test_lightning_fit_names_an_argument_its_classes_refuse(capsys, options, message):
    assert lightning_main([*FIT, "--data.init_args.data_dir", "data", *options]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith("lightning: ") and message in line
    assert not Path("logs").exists() and not Path("data").exists()


def test_an_image_method_refuses_no_rotation_bins_or_no_pixel_size():
    from nerf_transporter.methods import TransporterSE2

    with pytest.raises(ValueError, match="n_rotations must be >= 1, got 0"):
        TransporterSE2(n_rotations=0)
    with pytest.raises(ValueError, match=r"pixel_size must be > 0 \(metres per pixel\), got 0"):
        TransporterSE2(pixel_size=0.0)


def test_a_fit_that_cannot_write_its_data_names_the_folder(capsys):
    argv = [*FIT, "--data.init_args.data_dir", f"{A_FILE}/data", "--data.init_args.n_demos", "1"]
    assert lightning_main([*argv, "--trainer.max_steps", "1"]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"lightning: --data-dir {A_FILE}/data/block-insertion-normal-train")
    assert "cannot be written" in line and "is not a folder" in line
    assert not list(Path("logs").rglob("version_*"))


def results_file(path: Path, episodes: list[dict]) -> Path:
    """A `lightning test` results file of block-insertion in this world holding `episodes`."""
    record = {
        "method": "mira",
        "task": "block-insertion",
        "setting": "normal",
        "trained_setting": "normal",
        "split": "test",
        "imagery": "nerf",
        "checkpoint": None,
        "global_step": 2,
        "world": world_fingerprint(),
        **summarize(episodes),
        "episode_results": episodes,
    }
    path.write_text(json.dumps(record))
    return path


ACTION = {"pick": [0.5, 0.0, 0.05, 0, 0, 0, 1], "place": [0.6, 0.1, 0.05, 0, 0, 0, 1]}
FAILED = {"seed": 1, "success": False, "failure": NOT_ACHIEVED, "error": None, "action": ACTION}


def no_replay(*args, **kwargs):
    raise AssertionError("a scene was replayed")


@pytest.mark.parametrize(
    ("episode", "message"),
    [
        (
            {key: value for key, value in FAILED.items() if key != "failure"},
            "episode_results[0] (seed 1) failed without its reason: failure is null, not a string",
        ),
        (
            FAILED | {"action": [0.5, 0.0, 0.05, 0, 0, 0, 1] * 2},
            "episode_results[0] (seed 1): action is [0.5, 0.0, 0.05, 0, 0, 0, 1, 0.5, 0.0, 0.0",
        ),
        (
            FAILED | {"action": {"pick": ACTION["pick"], "place": [0.6, "x"]}},
            "episode_results[0] (seed 1): action is {",
        ),
    ],
    ids=["no-failure", "list-action", "short-place"],
)
def test_failures_names_an_episode_it_cannot_class_before_any_replay(
    capsys, monkeypatch, episode, message
):
    monkeypatch.setattr(failures, "make_env", no_replay)
    good = results_file(Path("good.json"), [FAILED])
    bad = results_file(Path("bad.json"), [episode])
    assert cli_main(["failures", str(good), str(bad), "--no-progress"]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"nerf-transporter failures: {bad}: {message}")


def test_failures_refuses_an_unwritable_json_before_any_replay(capsys, monkeypatch):
    monkeypatch.setattr(failures, "make_env", no_replay)
    good = results_file(Path("good.json"), [FAILED])
    for target, problem in ((f"{A_FILE}/out.json", "is not a folder"), (".", "is a folder")):
        assert cli_main(["failures", str(good), "--json", target, "--no-progress"]) == 2
        line = one_line(capsys.readouterr().err)
        assert line.startswith(f"nerf-transporter failures: --json {target} ") and problem in line


def test_report_refuses_an_unwritable_plot(capsys):
    Path("results").mkdir()
    assert cli_main(["report", "results", "--plot", f"{A_FILE}/table.png"]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"nerf-transporter report: --plot {A_FILE}/table.png cannot be written")


def generate_args(*changes: str) -> list[str]:
    """`nerf-transporter generate` of one oracle episode into data/ (later options override)."""
    return ["generate", *cli_args("data", *changes)]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (["--workers", "0"], "--workers must be >= 1, got 0"),
        (["--workers", "-2"], "--workers must be >= 1, got -2"),
        (["--nerf-image-size", "0x0"], "--nerf-image-size must be ROWSxCOLS, each >= 1, got 0x0"),
        (["--nerf-image-size", "48x0"], "--nerf-image-size must be ROWSxCOLS, each >= 1, got 48x0"),
        (["--data-dir", f"{A_FILE}/data"], f"--data-dir {A_FILE}/data/block-insertion-normal"),
    ],
    ids=["workers0", "workers-2", "size0x0", "size48x0", "data-dir"],
)
def test_generate_refuses_bad_options_before_any_rollout(fake_world, capsys, changes, message):
    assert cli_main(generate_args(*changes)) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"nerf-transporter generate: {message}")
    assert not Path("data").exists()


def test_generate_reads_a_complete_dataset_from_a_folder_it_need_not_write(
    fake_world, capsys, monkeypatch
):
    assert cli_main(generate_args()) == 0
    monkeypatch.setattr("nerf_transporter.atomic.unwritable_reason", lambda folder: "read-only")
    assert cli_main(generate_args()) == 0  # nothing to write: not refused
    assert cli_main(generate_args("--episodes", "2")) == 2  # an episode to write: refused
    assert "cannot be written: read-only" in capsys.readouterr().err


def test_dataset_info_names_a_corrupt_failed_seed_record(fake_world, capsys):
    dataset = gen.generate_dataset(
        gen.GenerationConfig("block-insertion", imagery="oracle", pixel_size=PIXEL, nerf_views=2),
        1,
        "data",
        progress=False,
    )
    record = dataset / ep.FAILED_DIR / "7.json"
    record.parent.mkdir(exist_ok=True)
    record.write_bytes(b"\x00\x01 not json")
    for verify, status in ((["--verify"], 1), ([], 0)):  # --verify: exit 1 on any problem
        assert cli_main(["dataset-info", str(dataset), *verify]) == status
        out, err = capsys.readouterr()
        assert f"problem   failed-seed record {record} is corrupt" in out and not err
        assert ("verified  NO" in out) == bool(verify)


def test_oracle_refuses_a_negative_seed(capsys):
    assert cli_main(["oracle", "--task", "block-insertion", "--seed", "-5"]) == 2
    line = one_line(capsys.readouterr().err)
    assert line == "oracle: --seed must be >= 0 (a scene's seed), got -5"


POSE = ([0.5, 0.0, 0.05], [0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize(
    ("pick", "dtype"),
    [
        ((np.array([0.5, 0.0, 0.05]) + 1e-3j, POSE[1]), "complex128"),
        ((["0.5", "0.0", "0.05"], POSE[1]), "<U4"),
        ((POSE[0], [False, False, False, True]), "bool"),
    ],
    ids=["complex", "text", "bool"],
)
def test_the_gym_env_refuses_a_pose_of_other_than_real_numbers(pick, dtype):
    env = gymnasium.make(env_id("block-insertion"))
    env.reset(seed=3)
    with pytest.raises(ValueError, match=rf"action\['pick'\] holds {dtype} values .*real numbers"):
        env.step({"pick": pick, "place": POSE})
    env.close()


def test_the_gym_env_names_a_reset_after_close():
    env = gymnasium.make(env_id("block-insertion"))
    env.reset(seed=3)
    env.close()
    with pytest.raises(RuntimeError, match=r"reset\(\) after close\(\): make a new environment"):
        env.reset(seed=3)
