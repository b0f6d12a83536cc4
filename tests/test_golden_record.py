"""Golden record: a refactor changes no number (issue 14).

Recorded once, with tiny settings, in tests/golden_record.json: the arrays and meta of a generated
oracle episode and of a NeRF episode, the losses of 5 training steps of every method on fixed seeds
(method + RavensDataModule, as `lightning fit` builds them) and the action of each trained method on
a fixed observation. Every run recomputes them and compares: floats with rtol 1e-5 / atol 1e-7
(harmless reordering of float sums), integers, strings and shapes exactly.

Re-record deliberately, after a change that is meant to change numbers:
    NT_RECORD_GOLDEN=1 python -m pytest tests/test_golden_record.py
(with `-k` to re-record one section only); the recording tests then skip with what they wrote.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from nerf_transporter import geometry as g
from nerf_transporter.data import episode as ep
from nerf_transporter.data import generate as gen
from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.data.heightmap import heightmap_from_rgbd
from nerf_transporter.data.labels import heightmap_labels, mira_labels
from nerf_transporter.methods import METHODS

GOLDEN = Path(__file__).with_name("golden_record.json")
RECORD = os.environ.get("NT_RECORD_GOLDEN") == "1"
RTOL, ATOL = 1e-5, 1e-7

TASK = "block-insertion"
PIXEL = 0.025  # 40 x 20 images
N_ROTATIONS = 4
NERF = dict(
    nerf_views=4,
    nerf_image_size=(30, 40),
    imagery_options={
        "iterations": 20,
        "batch_rays": 256,
        "voxel_size": 0.0125,
        "floor_cell": 0.0125,
    },
)
DATA = dict(
    task=TASK,
    n_demos=2,
    batch_size=2,
    imagery="oracle",
    pixel_size=PIXEL,
    n_rotations=N_ROTATIONS,
    n_negative_views=3,
    nerf_views=0,
    samples_per_epoch=10,
    seed=0,
)
IMAGE_MODEL = dict(pixel_size=PIXEL, n_rotations=N_ROTATIONS, crop_size=8, width=8)
STEPS = 5
SAMPLES = 32


# one torch thread: the numbers must not depend on how reductions are split over threads
pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def oracle_data(tmp_path_factory) -> Path:
    """The dataset of DATA's training demos, made by RavensDataModule.prepare_data (as in `fit`)."""
    data_dir = tmp_path_factory.mktemp("golden-data")
    RavensDataModule(data_dir=str(data_dir), input_kind="imagery", **DATA).prepare_data()
    (dataset_dir,) = [path for path in data_dir.iterdir() if path.is_dir()]
    return dataset_dir


def first_episode(dataset_dir: Path) -> ep.Episode:
    return ep.load_episode(ep.list_episodes(dataset_dir)[0].path)


def array_summary(array: np.ndarray) -> dict[str, Any]:
    """Shape, dtype, sum, mean, std, min, max and SAMPLES evenly strided values of an array."""
    array = np.asarray(array)
    exact = array.dtype.kind in "biu"
    values = array.reshape(-1)
    wide = values.astype(np.int64 if exact else np.float64)
    as_number = int if exact else float
    strided = np.unique(np.linspace(0, values.size - 1, SAMPLES).round().astype(int))
    return {
        "shape": list(array.shape),
        "dtype": str(array.dtype),
        "sum": as_number(wide.sum()),
        "mean": float(wide.mean()),
        "std": float(wide.std()),
        "min": as_number(wide.min()),
        "max": as_number(wide.max()),
        "sample": [as_number(v) for v in wide[strided]],
    }


def episode_summary(episode: ep.Episode, grid: np.ndarray) -> dict[str, Any]:
    """Every stored array summarised, and the meta's numbers: seed, action, state, labels."""
    action = gen.action_from_meta(episode.meta)
    return {
        "arrays": {
            f"{group}/{name}": array_summary(array)
            for group, arrays in sorted(episode.arrays.items())
            for name, array in sorted(arrays.items())
        },
        "seed": episode.meta["seed"],
        "action": episode.meta["action"],
        "state": episode.meta["state"],
        "imagery_quality": episode.meta["imagery"]["quality"],
        "labels": {
            "mira": dataclasses.asdict(mira_labels(action, grid, PIXEL, N_ROTATIONS)),
            "heightmap": dataclasses.asdict(heightmap_labels(action, PIXEL, N_ROTATIONS)),
        },
    }


def observation(episode: ep.Episode, input_kind: str) -> dict[str, Any]:
    """What evaluation hands `act` for this scene (evaluation/rollout.py), from the episode."""
    if input_kind == "state":
        return {"state": np.asarray(episode.meta["state"], dtype=np.float32)}
    if input_kind == "heightmap":
        colour, height = heightmap_from_rgbd(episode.arrays["rgbd"], PIXEL)
        return {"heightmap": {"colour": colour, "height": height}}
    imagery = episode.arrays["imagery"]
    return {"imagery": {key: imagery[key] for key in ("colour", "height", "views")}}


def jsonable(value: Any) -> Any:
    """Tuples and numpy scalars of a record -> lists and Python numbers (as JSON reads them back)."""
    if isinstance(value, dict):
        return {key: jsonable(item) for key, item in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [jsonable(item) for item in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def assert_same(recorded: Any, measured: Any, where: str) -> None:
    """Floats within RTOL/ATOL, everything else (keys, lengths, ints, strings, None) exactly."""
    if isinstance(recorded, dict):
        assert isinstance(measured, dict) and sorted(measured) == sorted(recorded), (
            f"{where}: keys {sorted(measured) if isinstance(measured, dict) else measured!r} "
            f"differ from the recorded {sorted(recorded)}"
        )
        for key in recorded:
            assert_same(recorded[key], measured[key], f"{where}.{key}")
    elif isinstance(recorded, list):
        assert isinstance(measured, list) and len(measured) == len(recorded), (
            f"{where}: {measured!r} differs from the recorded {recorded!r}"
        )
        for i, (a, b) in enumerate(zip(recorded, measured, strict=True)):
            assert_same(a, b, f"{where}[{i}]")
    elif isinstance(recorded, float):
        assert isinstance(measured, float), f"{where}: {measured!r} is not a float ({recorded!r})"
        np.testing.assert_allclose(measured, recorded, rtol=RTOL, atol=ATOL, err_msg=where)
    else:
        assert type(measured) is type(recorded) and measured == recorded, (
            f"{where}: {measured!r} differs from the recorded {recorded!r}"
        )


def check(section: str, measured: Any) -> None:
    """Compare `measured` with the recorded section (with NT_RECORD_GOLDEN=1: record it, skip)."""
    measured = jsonable(measured)
    record = json.loads(GOLDEN.read_text()) if GOLDEN.exists() else {}
    if RECORD:
        record[section] = measured
        GOLDEN.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
        pytest.skip(f"recorded {section} in {GOLDEN.name}")
    if section not in record:
        test_file = f"{GOLDEN.parent.name}/{Path(__file__).name}"
        pytest.fail(
            f"{GOLDEN} has no {section!r}: after a change meant to change numbers, record it with "
            f"NT_RECORD_GOLDEN=1 python -m pytest {test_file}"
        )
    assert_same(record[section], measured, section)


def test_oracle_episode(oracle_data):
    check("oracle_episode", episode_summary(first_episode(oracle_data), g.view_grid("normal")))


def test_nerf_episode(tmp_path):
    config = gen.GenerationConfig(TASK, imagery="nerf", pixel_size=PIXEL, **NERF)
    outcome = gen.generate_episode(config, tmp_path, 0)
    assert outcome.success, outcome.reason
    check("nerf_episode", episode_summary(first_episode(tmp_path), config.grid))


def make_method(name: str, episode: ep.Episode):
    cls = METHODS[name]
    if cls.input_kind == "state":
        return cls(state_dim=len(episode.meta["state"]))
    return cls(**IMAGE_MODEL)


@pytest.mark.parametrize("name", sorted(METHODS))
def test_training_losses_and_action(name, oracle_data):
    """STEPS Adam steps on RavensDataModule batches, then `act` of the trained method."""
    episode = first_episode(oracle_data)
    torch.manual_seed(0)
    method = make_method(name, episode)
    datamodule = RavensDataModule(
        data_dir=str(oracle_data.parent),
        input_kind=method.input_kind,
        generate_missing=False,
        **DATA,
    )
    datamodule.setup("fit")
    optimiser = method.configure_optimizers()
    losses = []
    for batch in datamodule.train_dataloader():
        step = method.losses(batch)
        losses.append({key: float(value.detach()) for key, value in step.items()})
        optimiser.zero_grad()
        step["loss"].backward()
        optimiser.step()
    assert len(losses) == STEPS
    method.eval()
    with torch.no_grad():
        action = method.act(observation(episode, method.input_kind))
    check(f"method/{name}", {"losses": losses, "action": action})
