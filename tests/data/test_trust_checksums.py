"""Training reads only the files an episode was written with: each npz the DataModule loads is
checked against the checksum its meta.json records, and `lightning fit` on a damaged, replaced or
edited episode ends with one line naming the file and the command that regenerates the dataset
(exit status 2), not a traceback, before any step is trained."""

import json
import shutil
import sys
from pathlib import Path

import pytest

from nerf_transporter.cli import lightning_main
from nerf_transporter.data import episode as ep
from nerf_transporter.data.datamodule import RavensDataModule
from tests.helpers.fake_sim import PIXEL

DATASET = f"block-insertion-normal-train-oracle-px{PIXEL}"
REGENERATE = (
    "nerf-transporter generate --task block-insertion --setting normal --split train "
    "--episodes 3 --imagery oracle"
)


def heightmap_data(tmp_path: Path) -> RavensDataModule:
    """A DataModule of the heightmap methods (they read rgbd.npz) over 3 generated episodes."""
    module = RavensDataModule(
        task="block-insertion",
        n_demos=3,
        data_dir=str(tmp_path / "data"),
        imagery="oracle",
        pixel_size=PIXEL,
        nerf_views=2,
        input_kind="heightmap",
    )
    module.prepare_data()
    return module


def episodes(tmp_path: Path) -> list[Path]:
    return [ref.path for ref in ep.list_episodes(tmp_path / "data" / DATASET)]


def copy_rgbd_from_another_episode(tmp_path: Path) -> str:
    """A valid rgbd.npz of another episode (of another size or, if the same, another checksum)."""
    first, second = episodes(tmp_path)[:2]
    shutil.copyfile(second / "rgbd.npz", first / "rgbd.npz")
    return f"episode {first.name}: rgbd.npz "


def truncate_rgbd(tmp_path: Path) -> str:
    path = episodes(tmp_path)[0] / "rgbd.npz"
    path.write_bytes(path.read_bytes()[:1000])
    return f"episode {path.parent.name}: rgbd.npz is truncated or altered (1000 bytes"


def edit_the_place_pose(tmp_path: Path) -> str:
    path = episodes(tmp_path)[1] / "meta.json"
    meta = json.loads(path.read_text())
    meta["action"]["place"]["quat_xyzw"] = [0.0, 0.0, 0.0, 1.0]
    path.write_text(json.dumps(meta))
    return f"episode {path.parent.name}: meta.json does not match its checksum"


def test_a_valid_npz_copied_from_another_episode_is_not_trained_on(fake_world, tmp_path):
    """Both files load as npz; only the size and checksum meta.json records tell them apart."""
    module = heightmap_data(tmp_path)
    problem = copy_rgbd_from_another_episode(tmp_path)
    with pytest.raises(ep.CorruptEpisodeError) as raised:
        module.setup("fit")
    message = str(raised.value)
    assert problem in message and str(episodes(tmp_path)[0] / "rgbd.npz") in message
    assert REGENERATE in message and message.endswith("--regenerate")
    with pytest.raises(ep.CorruptEpisodeError, match=problem):
        ep.load_episode(episodes(tmp_path)[0], ["rgbd"])
    ep.load_episode(episodes(tmp_path)[0], [])  # meta.json alone is intact


@pytest.mark.parametrize(
    "damage",
    [copy_rgbd_from_another_episode, truncate_rgbd, edit_the_place_pose],
    ids=["rgbd-of-another-episode", "truncated-rgbd", "edited-meta"],
)
def test_lightning_fit_on_a_damaged_episode_names_it_and_the_fix(
    fake_world, tmp_path, monkeypatch, capsys, damage
):
    heightmap_data(tmp_path)
    problem = damage(tmp_path)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["lightning"])
    data = {
        "task": "block-insertion",
        "n_demos": 3,
        "data_dir": "data",
        "imagery": "oracle",
        "pixel_size": PIXEL,
        "nerf_views": 2,
        "generate_missing": False,
    }
    config = tmp_path / "fit.yaml"
    config.write_text(
        json.dumps(
            {
                "trainer": {"max_steps": 1, "accelerator": "cpu", "enable_progress_bar": False},
                "model": {
                    "class_path": "TransporterSE2",
                    "init_args": {"crop_size": 8, "width": 8},
                },
                "data": {"class_path": "RavensDataModule", "init_args": data},
            }
        )
    )
    assert lightning_main(["fit", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    (line,) = [line for line in err.splitlines() if line.startswith("lightning: ")]
    assert problem in line and f"{REGENERATE} --data-dir data" in line, err
    assert line.endswith("--regenerate") and "Traceback" not in err
    assert not list((tmp_path / "logs").rglob("*.ckpt"))  # no step was trained
