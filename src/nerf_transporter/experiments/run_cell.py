"""`nerf-transporter run-cell --task T --method M [--setting S] [--test-setting S] [--imagery
oracle]`: one cell of the results table, start to finish and resumable (docs/results.md, "How a
cell is measured").

fit (`configs/<task>[_<setting>].yaml` + `configs/model/<method>.yaml` + any `--config` overlays,
with the budget options applied) -> the checkpoint with the best closed-loop validation success
(the score `ModelCheckpoint(monitor="eval/success_rate")` stored in each checkpoint; rounds with
erred episodes are never chosen, ties go to the later step, as `evaluate-checkpoints` ranks them)
-> the first `--episodes` test seeds -> the cell JSON, written atomically to
`<results>/<task>[-<setting>]/<method>[-oracle].json` (`<task>-<setting>-trained-<setting>` for a
policy trained and tested in a setting other than Normal).

`--test-setting S` (another setting than `--setting`, e.g. `challenging`) tests the fit of the cell
`--setting` names, with the same options (`--episodes` included: it is part of the fit's protocol),
on the first test seeds of S: the run folder and checkpoint that cell names, never fitted again
(an error where that checkpoint is not under `--logs`; before that cell is measured, the fit it
will take: fitted there first, exactly as that cell would, where the fit is missing or
unfinished), with the same validation rounds on the training setting, tested in S (mira searches
S's view grid), written to `<results>/<task>-<S>/<row>.json`. Its protocol is the fit's tested in
S, with `trained_setting` and `fit_protocol_id` added, and the cell names its fit (`fit`: protocol
id, run folder, checkpoint); `--force` then tests that checkpoint again (a fresh fit is the training
setting's cell's `--force`; a cell of a checkpoint that cell no longer names is an error, not
skipped).

A cell's protocol is everything that decides its number but the code: task, setting, method,
imagery, demonstrations, steps, batch size, learning rate, resolution, validation and test
episodes, the model's architecture (its other arguments, e.g. width and crop size, so that a
`--config` overlay that widens the networks is another protocol) and, under `training`, every other
setting that changes what a fit learns where it differs from the value the cells so far were
fitted with (seed, gradient accumulation and clipping, precision, augmentation, optimizer, ...:
`training_settings`; where a fit runs, what it logs and how fast its data loads are no part of
it), and the NeRF imagery settings that differ from the reference imagery (`imagery_changes`:
the config's `imagery_config` and this code's defaults alike; a stored cell keeps the ones it
recorded). Each protocol fits in its own folder `<logs>/<task>[-<setting>]/<row>/<protocol id>/version_N`,
so a rerun resumes the latest run from its checkpoint of the highest step (wherever the folder was
moved; never a run whose saved config differs in such a setting), never trains a finished fit
again, and skips a cell whose JSON holds the same protocol (read by `experiments/cells.py`: a
cell of another world is an error); `--force` measures it again from a fresh fit, in a run folder
of its own that `--force` resumes until the cell is written from it (so an interrupted `--force`
continues where it stopped, in a later session too). One command at a time fits and validates a protocol, and one at a time tests it in a setting: each holds a lock in
the protocol's folder, and a second one exits naming the first (so a fit's two tests may run side
by side once it is validated). Before anything runs, the folders it will write (fit runs,
results, the imagery cache) are checked writable. An interrupted test resumes from the episodes it
finished (`evaluation.journal`, through `evaluate_checkpoints`). A test with erred episodes writes no cell (its
record stays in the run's `evaluation/`) and exits 1; a finished test whose cell could not be
written is taken from there by the next run instead of testing again. `--fit-only` runs only the
fit, without the closed-loop validation callback (a GPU machine without PyBullet); the same command
without it, where PyBullet is, validates the unscored checkpoints closed loop, picks the best and
tests it. The fit is `lightning fit` (`experiments.lightning_cli`), driven from Python.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import fcntl
import importlib
import json
import logging
import math
import os
import socket
import sys
import time
import warnings
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import torch
import yaml

from nerf_transporter.atomic import UnwritableError, unwritable_reason, write_json
from nerf_transporter.console import HelpFormatter
from nerf_transporter.data.observation import SceneSpec
from nerf_transporter.device_info import describe_device
from nerf_transporter.evaluation.callback import round_view_search
from nerf_transporter.evaluation.metrics import cell
from nerf_transporter.evaluation.rollout import DEFAULT_CACHE_DIR
from nerf_transporter.evaluation.testing import checkpoint_step, erred_episodes_text
from nerf_transporter.experiments.cells import (
    CellFileError,
    column_folder,
    cross_protocol,
    load_cell,
    load_record,
    protocol_id,
    row_key,
)
from nerf_transporter.experiments.checkpoints import (
    UntrustedCheckpointError,
    best_record,
    checkpoint_steps,
    config_callbacks,
    evaluate_checkpoints,
    validation_records,
)
from nerf_transporter.experiments.lightning_cli import build_cli
from nerf_transporter.experiments.runs import (
    NoRunToResumeError,
    claim_version,
    latest_checkpoint,
    removed_if_unused,
)
from nerf_transporter.methods import METHODS
from nerf_transporter.provenance import SEGMENTS, git_state, read_segments
from nerf_transporter.sim.registration import TASK_NAMES
from nerf_transporter.sim.tasks import SETTINGS
from nerf_transporter.splits import split_seed

CALLBACK = "SuccessRateCallback"
CHECKPOINT = "ModelCheckpoint"
OFFLINE_VIEW_SEARCH = "OfflineViewSearch"  # mira's view search on demonstrations; no gradients
MONITOR = "eval/success_rate"
FORCED = "forced-fit"  # in a run folder claimed by --force: resumed by --force until its cell lands
LOCK = ".run-cell.lock"  # in a protocol's folder: held by the one run-cell fitting or validating
TEST_LOCK = ".run-cell-test-{setting}.lock"  # there: held by the one run-cell testing in a setting
LOGGER = "lightning.pytorch.loggers.TensorBoardLogger"
# model arguments outside the protocol's "model" entry (the architecture): lr, pixel_size and
# n_rotations are protocol keys of their own; view_chunk (memory), log_images_every_n_steps
# (logging) and cuda_graphs (how the GPU runs the same arithmetic) change nothing that is learned;
# view_choice (mira's test-time rule) is a protocol key of its own
MODEL_ARGS_NOT_ARCHITECTURE = (
    "lr",
    "pixel_size",
    "n_rotations",
    "view_chunk",
    "view_choice",
    "log_images_every_n_steps",
    "cuda_graphs",
    "square_attention",  # a protocol key only where on (PROTOCOL_KEYS_BY_DEFAULT)
)
# settings that enter a protocol only where they differ from these values (all its cells were
# measured under them before the setting existed), so that those cells keep their protocol ids
PROTOCOL_KEYS_BY_DEFAULT = {
    ("model", "view_choice"): "max_logit",
    ("model", "square_attention"): False,
    ("data", "augment_distribution"): "uniform",
    ("data", "negative_transform"): "shared",
}


# the resolved config's settings beyond the protocol's own keys that change what a fit learns,
# with the value every cell so far was fitted with: a cell's protocol names those that differ
# (`training_settings`), so that the ids of cells fitted with these values stay the same. A
# setting named neither here nor in NOT_TRAINING counts as one that changes the fit, against None:
# e.g. a gradient clip, precision, optimizer or callback. A resolved config leaves out the
# settings that are None (`negative_view_scale: null` draws negatives uniformly).
TRAINING_DEFAULTS = {
    "seed_everything": 0,
    "trainer.accumulate_grad_batches": 1,
    "trainer.barebones": False,
    "trainer.fast_dev_run": False,
    "trainer.num_nodes": 1,
    "trainer.overfit_batches": 0.0,
    "trainer.reload_dataloaders_every_n_epochs": 0,
    "trainer.sync_batchnorm": False,
    "trainer.use_distributed_sampler": True,
    "data.class_path": "nerf_transporter.data.datamodule.RavensDataModule",
    "data.augment": True,
    "data.n_negative_views": 1,
    "data.n_val_demos": 0,
    "data.negative_view_scale": 0.15,
    "data.nerf_image_size": [480, 640],
    "data.nerf_views": 30,
    "data.samples_per_epoch": 1000,
    "data.seed": 0,
}
# settings outside `training_settings`: the protocol's own keys, and those that change where a
# fit runs (accelerator, devices: the cell records the machine), what it logs or tests, how fast
# its data loads, or which command started it
NOT_TRAINING = {
    "ckpt_path",
    "weights_only",
    *(
        f"trainer.{key}"
        for key in (
            "max_steps",
            "accelerator",
            "strategy",
            "devices",
            "logger",
            "log_every_n_steps",
            "enable_progress_bar",
            "enable_model_summary",
            "enable_checkpointing",
            "enable_autolog_hparams",
            "profiler",
            "default_root_dir",
            "model_registry",
            "detect_anomaly",
            "inference_mode",
            "check_val_every_n_epoch",
            "val_check_interval",
            "num_sanity_val_steps",
            "limit_val_batches",
            "limit_test_batches",
            "limit_predict_batches",
        )
    ),
    *(
        f"data.{key}"
        for key in (
            "task",
            "setting",
            "n_demos",
            "batch_size",
            "imagery",
            "pixel_size",
            "n_rotations",
            "test_episodes",
            "colour_augment",
            "imagery_config",  # the protocol's imagery_changes
            "data_dir",
            "num_workers",
            "pin_memory",
            "generate_missing",
            "generate_workers",
            "input_kind",
            "test_setting",
            "test_workers",
            *(key for section, key in PROTOCOL_KEYS_BY_DEFAULT if section == "data"),
        )
    ),
}


class CellError(ValueError):
    """A cell that cannot be run as asked (bad option, config or results file)."""


def config_files(config_dir: Path, task: str, setting: str, method: str | None) -> list[Path]:
    """The task's full config for the setting and the method's overlay (none for no method)."""
    stem = task.replace("-", "_") + ("" if setting == "normal" else f"_{setting}")
    files = [config_dir / f"{stem}.yaml"]
    files += [config_dir / "model" / f"{method}.yaml"] if method else []
    for path in files:
        if not path.is_file():
            available = sorted(p.name for p in config_dir.glob("*.yaml"))
            raise CellError(
                f"no config {path} for {task} {setting}{f' / {method}' if method else ''} "
                f"(task configs in {config_dir}: {', '.join(available) or 'none'})"
            )
    return files


def resolve_config(files: list[Path]) -> dict[str, Any]:
    """The config LightningCLI resolves from `files` (defaults filled in, class paths in full),
    without the seed and accelerator lines it logs when it builds the trainer."""
    args: list[str] = []
    for path in files:
        args += ["--config", str(path)]
    disabled = logging.root.manager.disable
    logging.disable(logging.INFO)
    try:
        cli = build_cli_from_python(args, run=False)
    finally:
        logging.disable(disabled)
    return yaml.safe_load(cli.parser.dump(cli.config))


def build_cli_from_python(args: list[str], **options: Any) -> Any:
    """`build_cli(args)` without LightningCLI's warning that `args` came with a command line:
    run-cell drives LightningCLI from Python on purpose, with its own arguments."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*LightningCLI's args parameter is intended")
        return build_cli(args, **options)


def check_model(config: dict[str, Any], method: str) -> None:
    """CellError where the resolved config's model is not `method`'s class (a `--config` overlay
    setting `model.class_path` would fit another method under this one's name)."""
    class_path = config["model"].get("class_path", "")
    module, _, name = class_path.rpartition(".")
    try:
        model = getattr(importlib.import_module(module), name)  # imported by the config resolved
    except (ImportError, AttributeError, ValueError):
        model = None
    if model is not METHODS[method]:
        raise CellError(
            f"the config's model is {class_path or 'missing'}, not {method}'s class "
            f"{METHODS[method].__module__}.{METHODS[method].__name__}: --method names what is fitted"
        )


def _callback(config: dict[str, Any], name: str) -> dict[str, Any]:
    found = config_callbacks(config, name)
    if len(found) != 1:
        raise CellError(
            f"the config has {len(found)} {name} callbacks, run-cell needs one: it picks the "
            f"checkpoint by closed-loop validation success ({CALLBACK} + {CHECKPOINT} monitoring "
            f"{MONITOR}, as in configs/<task>.yaml)"
        )
    found[0].setdefault("init_args", {})
    return found[0]["init_args"]


def apply_budget(
    config: dict[str, Any],
    *,
    steps: int | None = None,
    batch_size: int | None = None,
    lr: float | None = None,
    episodes: int | None = None,
    imagery: str | None = None,
    val_every: int | None = None,
    val_episodes: int | None = None,
    eval_workers: int | None = None,
) -> dict[str, Any]:
    """A copy of `config` with the given options in place (None keeps the config's value);
    checks that validation checkpoints fall on the last step."""
    config = copy.deepcopy(config)
    trainer, model, data = (config.setdefault(key, {}) for key in ("trainer", "model", "data"))
    model_args, data_args = model.setdefault("init_args", {}), data.setdefault("init_args", {})
    validation, checkpoint = _callback(config, CALLBACK), _callback(config, CHECKPOINT)
    if checkpoint.get("monitor") != MONITOR:
        raise CellError(
            f"the config's {CHECKPOINT} monitors {checkpoint.get('monitor')}, not {MONITOR}"
        )
    updates = [
        (trainer, "max_steps", steps),
        (data_args, "batch_size", batch_size),
        (model_args, "lr", lr),
        (data_args, "test_episodes", episodes),
        (data_args, "imagery", imagery),
        (validation, "every_n_steps", val_every),
        (checkpoint, "every_n_train_steps", val_every),
        (validation, "episodes", val_episodes),
        (validation, "eval_workers", eval_workers),
    ]
    for section, key, value in updates:
        if value is not None:
            if not isinstance(value, str) and not (math.isfinite(value) and value > 0):
                raise CellError(f"{key} must be > 0 and finite, got {value}")
            section[key] = value
    every, steps = validation.get("every_n_steps"), trainer.get("max_steps")
    if checkpoint.get("every_n_train_steps") != every:
        raise CellError(
            f"validation every {every} steps but checkpoints every "
            f"{checkpoint.get('every_n_train_steps')}: they must coincide (--val-every sets both)"
        )
    if not isinstance(steps, int) or steps <= 0 or steps % every:
        raise CellError(
            f"{steps} training steps is not a multiple of the validation interval {every}: the "
            "last steps would have no validated checkpoint (set --steps or --val-every)"
        )
    return config


def without_closed_loop(config: dict[str, Any]) -> dict[str, Any]:
    """`config` for a fit on a machine without PyBullet: no closed-loop validation callback, and
    the checkpoints at the same steps, all kept, unscored (run-cell validates them afterwards)."""
    config = copy.deepcopy(config)
    closed_loop = config_callbacks(config, CALLBACK)
    trainer = config["trainer"]
    trainer["callbacks"] = [c for c in trainer["callbacks"] if c not in closed_loop]
    checkpoint = _callback(config, CHECKPOINT)
    for key in ("monitor", "mode"):
        checkpoint.pop(key, None)
    checkpoint.update(save_top_k=-1, filename="step{step:06d}", auto_insert_metric_name=False)
    return config


def cell_protocol(config: dict[str, Any], method: str, input_kind: str) -> dict[str, Any]:
    """What decides a cell's number apart from the code, read from its resolved config."""
    model = config["model"].get("init_args", {})
    architecture = {k: v for k, v in model.items() if k not in MODEL_ARGS_NOT_ARCHITECTURE}
    data = config["data"].get("init_args", {})
    validation = _callback(config, CALLBACK)
    protocol = {
        "task": data["task"],
        "setting": data.get("setting", "normal"),
        "method": method,
        "imagery": data.get("imagery", "nerf") if input_kind == "imagery" else None,
        "n_demos": data.get("n_demos"),
        "steps": config["trainer"]["max_steps"],
        "batch_size": data.get("batch_size"),
        "lr": model.get("lr"),
        "pixel_size": data.get("pixel_size"),
        "n_rotations": data.get("n_rotations"),
        "validation_every": validation["every_n_steps"],
        "validation_episodes": validation.get("episodes"),
        "test_episodes": data.get("test_episodes"),
        "model": architecture,
    }
    if data.get("colour_augment"):
        # only when on, so that the protocol ids of cells measured before the option stay the same
        protocol["colour_augment"] = True
    if input_kind == "imagery" and (changes := imagery_changes(data)):
        protocol["imagery_changes"] = changes
    for (section, key), default in PROTOCOL_KEYS_BY_DEFAULT.items():
        value = (model if section == "model" else data).get(key, default)
        if value != default:
            protocol[key] = value
    if training := training_settings(config):
        protocol["training"] = training
    return protocol


def imagery_changes(data: dict[str, Any]) -> dict[str, Any]:
    """The NeRF imagery settings of a resolved config's `data.init_args` that differ from the
    reference imagery (`SceneSpec.imagery_changes`): its `imagery_config` and the defaults of
    `ImageryConfig` in this code alike; {} for oracle imagery."""
    try:
        scene = SceneSpec(
            data["task"],
            imagery=data.get("imagery", "nerf"),
            pixel_size=data.get("pixel_size") or SceneSpec.pixel_size,
            imagery_options=data.get("imagery_config") or {},
        )
    except (TypeError, ValueError) as error:
        raise CellError(f"data.imagery_config: {error}") from error
    return scene.imagery_changes()


def training_settings(config: dict[str, Any]) -> dict[str, Any]:
    """{dotted key: value} of the settings of the resolved run config `config` that change what a
    fit learns beyond the protocol's own keys, where they differ from the value every cell so far
    was fitted with (`TRAINING_DEFAULTS`): callbacks other than the validation and checkpoint ones,
    and every setting not in `NOT_TRAINING`, e.g. `trainer.gradient_clip_val` or `data.augment`."""
    trainer, data = config.get("trainer") or {}, config.get("data") or {}
    sections = {"trainer", "model", "data"}
    settings = dict.fromkeys(TRAINING_DEFAULTS)  # left out of a resolved config: None
    settings |= {key: value for key, value in config.items() if key not in sections}
    settings |= {f"trainer.{key}": value for key, value in trainer.items() if key != "callbacks"}
    settings |= {f"data.{key}": value for key, value in (data.get("init_args") or {}).items()}
    settings["data.class_path"] = data.get("class_path")
    known = {CALLBACK, CHECKPOINT, OFFLINE_VIEW_SEARCH}  # callbacks that leave the fit as it is
    others = [
        callback
        for callback in trainer.get("callbacks") or []
        if str(callback.get("class_path", "")).rsplit(".", 1)[-1] not in known
    ]
    settings["trainer.callbacks"] = others or None
    return {
        key: value
        for key, value in sorted(settings.items())
        if key not in NOT_TRAINING and value != TRAINING_DEFAULTS.get(key)
    }


def cell_name(protocol: dict[str, Any]) -> tuple[str, str]:
    """(column folder, row `<method>[-oracle]`) of a cell (`column_folder`)."""
    trained = protocol.get("trained_setting", protocol["setting"])
    column = column_folder(protocol["task"], protocol["setting"], trained)
    return column, row_key(protocol["method"], protocol["imagery"])


def fit_folder(logs: Path, fit: dict[str, Any]) -> Path:
    """The folder of the runs of the fit protocol `fit`: `<logs>/<task>[-<setting>]/<row>/<id>`."""
    row = row_key(fit["method"], fit["imagery"])
    return logs / column_folder(fit["task"], fit["setting"]) / row / protocol_id(fit)


def cell_path(results: Path, protocol: dict[str, Any]) -> Path:
    column, row = cell_name(protocol)
    return results / column / f"{row}.json"


def _flat(settings: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested settings as one level of dotted keys."""
    flat = {}
    for key, value in settings.items():
        if isinstance(value, dict):
            flat |= _flat(value, f"{prefix}{key}.")
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def table_differences(protocol: dict[str, Any], table_cell: Path) -> str | None:
    """How a sweep's `protocol` differs from the table's cell `table_cell` of its row and column
    (each differing setting, the cell's value and this one's; "-" where one has none), or None
    where there is no readable cell there or nothing differs. A sweep meant to change one knob
    shows here every other one it changed too (an overlay of the cell's left out, say)."""
    try:
        table_protocol = json.loads(table_cell.read_text())["protocol"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    ours, theirs = _flat(protocol), _flat(table_protocol)
    changed = [
        f"{key} (the cell: {theirs.get(key, '-')}; this: {ours.get(key, '-')})"
        for key in sorted(ours.keys() | theirs.keys())
        if ours.get(key, "-") != theirs.get(key, "-")
    ]
    if not changed:
        return None
    return f"run-cell: this protocol differs from the table's cell {table_cell} in " + ", ".join(
        changed
    )


def stored_protocol(cell: dict[str, Any], input_kind: str) -> dict[str, Any]:
    """A stored cell's protocol as this code reads it from the cell's resolved config (its fit's,
    tested in the cell's setting for a cross-setting cell), so that a cell written before the
    protocol gained a key still matches; its recorded protocol where the config cannot be read
    so."""
    try:
        fit = cell_protocol(cell["config"], cell["method"], input_kind)
    except (KeyError, TypeError, AttributeError, CellError):
        return cell["protocol"]
    # the imagery it was measured on is the recorded one: a config leaves ImageryConfig's defaults
    # out, and those of the code that measured it may not be this code's (none recorded: the
    # reference imagery, under which every cell was measured before the key existed)
    fit.pop("imagery_changes", None)
    if recorded := cell["protocol"].get("imagery_changes"):
        fit["imagery_changes"] = recorded
    return cross_protocol(fit, cell["setting"]) if "trained_setting" in cell["protocol"] else fit


def measured(
    path: Path, protocol: dict[str, Any], input_kind: str, fit_cell: Path | None = None
) -> bool:
    """Whether `path` holds this cell for `protocol`; a cell of another protocol is an error, and
    so is a cross-setting cell that tested another checkpoint than the one `fit_cell` (the cell of
    its fit, in the training setting) names, where that holds the cell of its fit."""
    if not path.exists():
        return False
    try:
        cell = load_cell(path)
    except CellFileError as error:
        raise CellError(f"{error}; --force replaces it") from error
    stored = stored_protocol(cell, input_kind)
    if stored == protocol:
        if fit_cell is not None:
            _check_tested_fit(path, cell, fit_cell, input_kind)
        return True
    changed = ", ".join(
        f"{key} {stored.get(key)} there, {protocol.get(key)} here"
        for key in sorted(set(stored) | set(protocol))
        if stored.get(key) != protocol.get(key)
    )
    raise CellError(
        f"{path} holds this cell under another protocol ({changed}); --force replaces it, "
        "--results <folder> keeps both (an earlier recipe's cell moves to "
        "<results>/archive/recipe-<name>/ first, docs/results.md)"
    )


def _check_tested_fit(path: Path, cell: dict[str, Any], fit_cell: Path, input_kind: str) -> None:
    """CellError where the cross-setting cell `cell` (in `path`) tested another checkpoint than
    `fit_cell` names, where that holds the cell of its fit (measured again since)."""
    if not fit_cell.exists():
        return
    try:
        fit = load_cell(fit_cell)
    except CellFileError as error:
        raise CellError(f"{error}; a test in another setting tests the fit it names") from error
    if protocol_id(stored_protocol(fit, input_kind)) != cell["protocol"]["fit_protocol_id"]:
        return
    tested, named = cell["fit"]["checkpoint"], fit["checkpoint"]["path"]
    if Path(tested).parts[-4:] != Path(named).parts[-4:]:  # wherever the logs were moved
        raise CellError(
            f"{path} tested {tested}, and {fit_cell}, the cell of its fit, now names {named}: "
            "--force tests that checkpoint"
        )


@contextlib.contextmanager
def cell_lock(folder: Path, name: str = LOCK) -> Iterator[None]:
    """Hold the lock `folder/<name>` while the block runs: one run-cell at a time per protocol
    folder and lock (the lock goes with its process, also one killed); CellError naming the holder
    where another command holds it."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / name, "a+") as file:
        try:
            fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            file.seek(0)
            holder = file.read().strip() or "another process"
            raise CellError(
                f"this cell is being measured by {holder} (it holds {folder / name}): one run-cell "
                "at a time per cell; wait for it to end, or stop it and run again"
            ) from None
        file.seek(0)
        file.truncate()
        started = datetime.now(timezone.utc).isoformat(timespec="seconds")
        file.write(f"run-cell, pid {os.getpid()} on {socket.gethostname()}, since {started}\n")
        file.flush()
        yield


def check_writable(folders: list[tuple[str, Path]]) -> None:
    """CellError naming the first of `folders` ((what it holds, folder)) no file can be written
    into, before anything is spent."""
    for what, folder in folders:
        if reason := unwritable_reason(folder):
            raise CellError(
                f"the {what} folder {folder} cannot be written ({reason}); nothing was run"
            )


def finished_test(
    run_dir: Path, checkpoint: Path, protocol: dict[str, Any]
) -> dict[str, Any] | None:
    """A test record of `checkpoint` in the run's `evaluation/` on the protocol's test seeds,
    without erred episodes, of this world (`load_record`), under the protocol's view choice and
    the training's imagery settings: the test of a run whose cell could not be written. None
    where there is none."""
    seeds = [split_seed("test", index) for index in range(protocol["test_episodes"])]
    identity = (protocol["method"], protocol["setting"], protocol["imagery"])
    for path in sorted((run_dir / "evaluation").glob(f"{checkpoint.stem}-test-*.json")):
        try:
            record = load_record(path)
        except CellFileError:
            continue  # damaged, or measured in another world: tested again
        if (
            "protocol" not in record
            and Path(record.get("checkpoint") or "").name == checkpoint.name
            and (record["method"], record["setting"], record.get("imagery")) == identity
            and not record.get("errors")
            and not record.get("imagery_options")  # an imagery candidate's test, not the cell's
            and record.get("test_time_options", {}).get("view_choice", "max_logit")
            == protocol.get("view_choice", PROTOCOL_KEYS_BY_DEFAULT["model", "view_choice"])
            and [episode["seed"] for episode in record.get("episode_results", [])] == seeds
            and isinstance(record.get("wall_s"), int | float)
        ):
            return record
    return None


def _names_run(cell: Path, run_dir: Path) -> bool:
    """Whether the cell file `cell` was measured in `run_dir` (its recorded run folder ends in
    the same protocol folder and version, wherever the logs were moved)."""
    try:
        recorded = Path(json.loads(cell.read_text())["run_dir"])
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return recorded.parts[-2:] == run_dir.parts[-2:]


def fit_run(runs: Path, force: bool, cell: Path) -> tuple[Path, Path | None]:
    """(run folder, checkpoint to resume from or None): the latest run under `runs` with a
    readable checkpoint and its checkpoint of the highest step (`latest_checkpoint`); with `force`
    only where that run was itself claimed by `force` (marked `FORCED`) and `cell` was not yet
    measured in it (an interrupted `--force` resumes). Otherwise, or where there is none, a newly
    claimed `version_N`, marked where `force` claimed it."""
    try:
        checkpoint = latest_checkpoint(runs)
    except NoRunToResumeError:
        checkpoint = None
    if checkpoint is not None:
        run_dir = checkpoint.parent.parent
        if not force or ((run_dir / FORCED).exists() and not _names_run(cell, run_dir)):
            return run_dir, checkpoint
    run_dir = runs / f"version_{claim_version(runs)}"
    if force:
        (run_dir / FORCED).write_text(f"claimed by run-cell --force to measure {cell} again\n")
    return run_dir, None


def named_fit(cell: Path, fit: dict[str, Any], runs: Path, input_kind: str) -> Path | None:
    """The checkpoint under `runs` that the cell file `cell` tested, where it holds the cell of the
    fit protocol `fit` (a test of that fit in another setting tests the same checkpoint); None
    where it holds no cell of `fit` (none yet, or one of another protocol). CellError where it
    cannot be read, or names a checkpoint that is not under `runs` (wherever the logs were moved,
    `<protocol id>/version_N/checkpoints/<name>` of `runs`' protocol id)."""
    if not cell.exists():
        return None
    try:
        stored = load_cell(cell)
    except CellFileError as error:
        raise CellError(f"{error}; a test in another setting tests the fit it names") from error
    if stored_protocol(stored, input_kind) != fit:
        return None
    recorded = Path(stored["checkpoint"]["path"])
    checkpoint = runs.joinpath(*recorded.parts[-3:])
    if recorded.parts[-4:-3] != (runs.name,) or not checkpoint.is_file():
        raise CellError(
            f"{cell} was measured with {recorded}, and there is no such checkpoint {checkpoint}: "
            "a test in another setting tests the fit of its training setting's cell (--logs "
            "names the folder that holds the fit runs; --force without --test-setting fits "
            "that cell again)"
        )
    return checkpoint


def chosen_record(
    validation: list[dict[str, Any]], run_dir: Path, named: Path | None
) -> dict[str, Any]:
    """The validation record of the checkpoint to test: of `named` (`named_fit`) where given,
    else the best (`best_record`); CellError where there is none."""
    if named is None:
        chosen = best_record(validation)
    else:
        chosen = next((r for r in validation if Path(r["checkpoint"]).name == named.name), None)
    if chosen is None:
        raise CellError(
            f"no checkpoint under {run_dir} has a validation round without erred episodes; see "
            "the fit's log, fix the cause and run again with --force"
            if named is None
            else f"{named} has no validation round in {run_dir}"
        )
    return chosen


def check_fitted_as(run_dir: Path, config: dict[str, Any]) -> None:
    """CellError naming the settings that change what a fit learns (`training_settings`) where a
    config the run `run_dir` was fitted with (`config*.yaml`, saved there by Lightning) differs
    from `config` in one: a run is neither resumed nor tested under other settings (a run that an
    earlier run-cell, whose protocol left such a setting out, fitted into this protocol's folder)."""
    wanted = training_settings(config)
    for saved in sorted(run_dir.glob("config*.yaml")):
        try:
            fitted = training_settings(yaml.safe_load(saved.read_text()) or {})
        except (OSError, yaml.YAMLError, AttributeError) as error:
            raise CellError(f"{saved} cannot be read as a run config ({error})") from error
        keys = sorted(
            key for key in set(fitted) | set(wanted) if fitted.get(key) != wanted.get(key)
        )
        if keys:
            differences = ", ".join(
                f"{key} {fitted.get(key, TRAINING_DEFAULTS.get(key))} there, "
                f"{wanted.get(key, TRAINING_DEFAULTS.get(key))} here"
                for key in keys
            )
            raise CellError(
                f"{run_dir} was fitted under other settings ({differences}; {saved}): a fit is "
                "not resumed nor tested under settings it was not fitted with; --force fits afresh"
            )


def fit(config: dict[str, Any], run_dir: Path, resume: Path | None, device: str) -> None:
    """`lightning fit` of `config` (handed over as YAML text: no file is left behind) logging into
    `run_dir`, from `resume` if given; the segment (start, commit, machine, wall-clock time once
    done) is recorded in `run_dir/fit-segments.json`."""
    run_dir.mkdir(parents=True, exist_ok=True)
    config = copy.deepcopy(config)
    config["trainer"]["logger"] = {
        "class_path": LOGGER,
        "init_args": {
            "save_dir": str(run_dir.parent),
            "name": "",
            "version": run_dir.name,
            "default_hp_metric": False,
        },
    }
    segments = read_segments(run_dir)
    segment = {
        "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "start_time": time.time(),
        "from_step": checkpoint_step(resume) if resume else 0,
        "git": git_state(),
        "machine": describe_device(device),
        "wall_s": None,
    }
    write_json(run_dir / SEGMENTS, segments + [segment])
    args = ["fit", "--config", yaml.safe_dump(config, sort_keys=False)]
    build_cli_from_python(args + (["--ckpt_path", str(resume)] if resume else []))
    segment["wall_s"] = time.time() - segment["start_time"]
    write_json(run_dir / SEGMENTS, segments + [segment])


def train_wall_s(run_dir: Path) -> float:
    """Wall-clock time of the run's fit segments; an interrupted one counts up to the newest
    checkpoint it wrote before the next segment started (the steps after it were trained again)."""
    checkpoints = [path.stat().st_mtime for path in (run_dir / "checkpoints").glob("*.ckpt")]
    segments = read_segments(run_dir)
    ends = [segment["start_time"] for segment in segments[1:]] + [float("inf")]
    total = 0.0
    for segment, next_start in zip(segments, ends, strict=True):
        if segment["wall_s"] is not None:
            total += segment["wall_s"]
        else:
            start = segment["start_time"]
            written = [mtime for mtime in checkpoints if start <= mtime < next_start]
            total += max(written, default=start) - start
    return total


def validate(
    run_dir: Path, protocol: dict[str, Any], device: str, workers: int | None
) -> list[dict[str, Any]]:
    """The run's validation rounds (`validation_records`), after running closed loop here the
    rounds its fit could not (checkpoints at validation steps saved without a score)."""
    episodes, setting = protocol["validation_episodes"], protocol["setting"]
    view_choice = protocol.get("view_choice", PROTOCOL_KEYS_BY_DEFAULT["model", "view_choice"])
    records = validation_records(run_dir, episodes, setting, view_choice)
    done = {record["global_step"] for record in records}
    every, steps = protocol["validation_every"], protocol["steps"]
    pending = [
        path
        for step, path in checkpoint_steps(run_dir)
        if step % every == 0 and 0 < step <= steps and step not in done
    ]
    if pending:
        evaluate_checkpoints(
            run_dir,
            "validation",
            episodes,
            only=pending,
            device=torch.device(device),
            workers=workers,
        )
        records = validation_records(run_dir, episodes, setting, view_choice)
    return records


def run_cell(
    *,
    task: str,
    method: str,
    setting: str = "normal",
    test_setting: str | None = None,
    imagery: str | None = None,
    steps: int | None = None,
    batch_size: int | None = None,
    lr: float | None = None,
    episodes: int = 100,
    val_every: int | None = None,
    val_episodes: int | None = None,
    overlays: list[Path] | None = None,
    config_dir: Path = Path("configs"),
    results: Path = Path("results"),
    logs: Path = Path("logs/cells"),
    force: bool = False,
    eval_workers: int | None = None,
    device: str | None = None,
    fit_only: bool = False,
    table: Path | None = None,
) -> tuple[Path, dict[str, Any] | None]:
    """Run one cell (see the module's docstring): trained in `setting`, tested in `test_setting`
    (default: `setting`). Returns (cell path, cell record); the record is None where the cell was
    already measured under this protocol, and holds no cell (nothing written) where test episodes
    erred (`errors` > 0). With `fit_only` (a machine without PyBullet): only the fit,
    `without_closed_loop`; returns (run folder, None). With `table` (the table's cell folder)
    other than `results` (a sweep), it first prints how this protocol differs from the table's
    cell of the same row and column, where there is one (`table_differences`)."""
    if method not in METHODS:
        raise CellError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    test_setting = test_setting or setting
    if test_setting not in SETTINGS:
        raise CellError(f"unknown test setting {test_setting!r}; valid: {', '.join(SETTINGS)}")
    # the code this process runs (validation and test run in it): a commit made while the cell
    # runs, hours later, does not change it
    code = git_state()
    input_kind = METHODS[method].input_kind
    if imagery is not None and input_kind != "imagery":
        raise CellError(
            f"--imagery applies to methods that read imagery; {method} reads {input_kind}"
        )
    files = config_files(config_dir, task, setting, method) + list(overlays or [])
    config = apply_budget(
        resolve_config(files),
        steps=steps,
        batch_size=batch_size,
        lr=lr,
        episodes=episodes,
        imagery=imagery,
        val_every=val_every,
        val_episodes=val_episodes,
        eval_workers=eval_workers,
    )
    check_model(config, method)
    fit_protocol = cell_protocol(config, method, input_kind)
    cross = test_setting != setting
    protocol = cross_protocol(fit_protocol, test_setting) if cross else fit_protocol
    path = cell_path(results, protocol)
    fit_cell = cell_path(results, fit_protocol) if cross else None  # the cell that names its fit
    if not force and measured(path, protocol, input_kind, fit_cell):
        return path, None
    sweep = table is not None and table.resolve() != results.resolve()
    if sweep and (differences := table_differences(protocol, cell_path(table, protocol))):
        print(differences)
    runs = fit_folder(logs, fit_protocol)
    folders = [("fit runs", runs)]
    if not fit_only:
        folders.append(("results", path.parent))
        if input_kind == "imagery":
            # validation's (None: it caches nothing) and the test's
            validation_cache = _callback(config, CALLBACK).get("cache_dir", DEFAULT_CACHE_DIR)
            caches = {validation_cache, DEFAULT_CACHE_DIR} - {None}
            folders += [("imagery cache", Path(cache)) for cache in sorted(caches)]
    check_writable(folders)
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    with cell_lock(runs):
        if not force and measured(path, protocol, input_kind, fit_cell):
            return path, None  # measured meanwhile by the command that held the lock
        # a cross-setting cell never fits afresh: its fit is the one its training setting's cell
        # names, or, before that cell is measured, the fit that cell will take
        named = (
            named_fit(fit_cell, fit_protocol, runs, input_kind) if fit_cell is not None else None
        )
        if named is not None:
            run_dir = named.parent.parent
        else:
            run_dir, resume = fit_run(runs, force and not cross, path)
            if resume is not None:
                check_fitted_as(run_dir, config)
            if resume is None or checkpoint_step(resume) < fit_protocol["steps"]:
                with removed_if_unused([run_dir] if resume is None else []):
                    fit(
                        without_closed_loop(config) if fit_only else config, run_dir, resume, device
                    )
        if fit_only:
            return run_dir, None
        validation = validate(run_dir, fit_protocol, device, eval_workers)
    chosen = chosen_record(validation, run_dir, named)
    with cell_lock(runs, TEST_LOCK.format(setting=test_setting)):
        if not force and measured(path, protocol, input_kind, fit_cell):
            return path, None  # measured meanwhile by the command that held the lock
        return _test(
            config,
            protocol,
            path,
            run_dir,
            chosen,
            validation,
            code=code,
            overlays=overlays,
            retest=force,
            eval_workers=eval_workers,
            device=device,
        )


def _test(
    config: dict[str, Any],
    protocol: dict[str, Any],
    path: Path,
    run_dir: Path,
    chosen: dict[str, Any],
    validation: list[dict[str, Any]],
    *,
    code: dict[str, Any],
    overlays: list[Path] | None,
    retest: bool,
    eval_workers: int | None,
    device: str,
) -> tuple[Path, dict[str, Any] | None]:
    """`run_cell` once its fit is validated and its test lock is held: test the `chosen`
    checkpoint in the protocol's setting (or take the finished test of a cell that could not be
    written, unless `retest`), write the cell."""
    checkpoint = Path(chosen["checkpoint"])
    record = None if retest else finished_test(run_dir, checkpoint, protocol)
    if record is not None:
        test_wall_s = record["wall_s"]
    else:
        start = time.perf_counter()
        (record,) = evaluate_checkpoints(
            run_dir,
            "test",
            protocol["test_episodes"],
            only=[checkpoint],
            setting=protocol["setting"],
            device=torch.device(device),
            workers=eval_workers,
        )
        test_wall_s = time.perf_counter() - start
    if record["errors"]:
        return path, record
    segments = read_segments(run_dir)
    payload = {
        "protocol": protocol,
        "protocol_id": protocol_id(protocol),
        **{key: protocol[key] for key in ("task", "setting", "method", "imagery")},
        **{key: record[key] for key in ("episodes", "successes", "success_rate", "ci_low")},
        **{key: record[key] for key in ("ci_high", "confidence", "errors", "erred_seeds")},
        # the project's stricter 6-DoF check (None where the test's records lack it)
        **{f"strict_{key}": record.get(f"strict_{key}") for key in ("successes", "success_rate")},
        **{f"strict_{key}": record.get(f"strict_{key}") for key in ("ci_low", "ci_high")},
        "failures": record["failures"],
        # mira: where the view search placed against the true view (`evaluation.view_search`)
        **({"view_search": record["view_search"]} if record.get("view_search") else {}),
        "test_seeds": [result["seed"] for result in record["episode_results"]],
        "checkpoint": {
            "path": chosen["checkpoint"],
            "step": chosen["global_step"],
            "validation_success_rate": chosen["success_rate"],
            "validation_successes": chosen["successes"],
            "validation_episodes": chosen["episodes"],
        },
        "validation": [
            {"step": r["global_step"], "success_rate": r["success_rate"]}
            | round_view_search(run_dir, r["global_step"])
            for r in validation
        ],
        "steps": protocol["steps"],
        "batch_size": protocol["batch_size"],
        "lr": protocol["lr"],
        "train_wall_s": train_wall_s(run_dir),
        "test_wall_s": test_wall_s,
        # episodes an interrupted test had finished: test_wall_s is the rest's
        **({"test_resumed_episodes": n} if (n := record.get("resumed_episodes")) else {}),
        "machine": {
            "fit": [segment["machine"] for segment in segments],
            "test": describe_device(device),
        },
        "torch": torch.__version__,
        "git": code,
        "fit_git": [segment["git"] for segment in segments],
        "world": record["world"],
        "run_dir": str(run_dir),
        **(
            {
                "fit": {
                    "protocol_id": protocol["fit_protocol_id"],
                    "run_dir": str(run_dir),
                    "checkpoint": chosen["checkpoint"],
                }
            }
            if "trained_setting" in protocol
            else {}
        ),
        "config": config,
        "overlays": [str(overlay) for overlay in overlays or []],
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "episode_results": [
            result | {"strict_success": result.get("strict_success")}
            for result in record["episode_results"]
        ],
    }
    try:
        write_json(path, payload)
    except OSError as error:
        raise CellError(
            f"could not write the cell {path} ({error}); its test is kept in "
            f"{run_dir / 'evaluation'}, and the same command writes the cell without testing again"
        ) from error
    return path, payload


def add_config_arguments(parser: argparse.ArgumentParser, applied_after: str) -> None:
    """`--config` overlays, applied after `applied_after`, and `--configs`, the config folder."""
    parser.add_argument(
        "--config",
        type=Path,
        action="append",
        default=[],
        help=f"another config applied after {applied_after} (repeatable)",
    )
    parser.add_argument("--configs", type=Path, default=Path("configs"), help="config folder")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter run-cell",
        description="One cell of the results table: fit, pick the checkpoint by closed-loop "
        "validation success, test on the first test seeds (of --test-setting, where given), write "
        "the cell JSON. Resumable; a cell already measured under the same protocol is skipped.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--task", required=True, choices=TASK_NAMES)
    parser.add_argument("--method", required=True, choices=list(METHODS))
    parser.add_argument(
        "--setting", default="normal", choices=SETTINGS, help="the setting trained (and tested) in"
    )
    parser.add_argument(
        "--test-setting",
        choices=SETTINGS,
        help="test the fit of the --setting cell (the same options; fitted first where it is "
        "missing or unfinished, never again) in this setting, as a cell of its own "
        "(results/<task>-<setting>/), e.g. challenging (default: --setting)",
    )
    parser.add_argument(
        "--imagery",
        choices=("nerf", "oracle"),
        help="imagery of an imagery method, in training and test (default: the config's, nerf)",
    )
    parser.add_argument("--steps", type=int, help="training steps (default: the task config's)")
    parser.add_argument("--batch-size", type=int, help="default: the task config's")
    parser.add_argument("--lr", type=float, help="learning rate (default: the config's)")
    parser.add_argument("--episodes", type=int, default=100, help="test episodes (first seeds)")
    parser.add_argument("--val-every", type=int, help="steps between validation rounds")
    parser.add_argument("--val-episodes", type=int, help="validation episodes per round")
    add_config_arguments(parser, "the task's and the method's")
    parser.add_argument(
        "--results",
        type=Path,
        default=Path("results"),
        help="cell folder; another than results/ is a sweep's, and run-cell first prints every "
        "setting in which its protocol differs from the table's cell in results/",
    )
    parser.add_argument("--logs", type=Path, default=Path("logs/cells"), help="fit runs folder")
    parser.add_argument(
        "--force",
        action="store_true",
        help="measure again from a fresh fit (one interrupted before its cell was written is "
        "resumed by --force again)",
    )
    parser.add_argument(
        "--eval-workers",
        type=int,
        help="processes running validation and test episodes (default: one per available core)",
    )
    parser.add_argument("--device", help="torch device (default: cuda if present)")
    parser.add_argument(
        "--fit-only",
        action="store_true",
        help="only the fit, without closed-loop validation (for a GPU machine without PyBullet); "
        "bring its run folder back and run the same command without --fit-only, which validates "
        "its checkpoints and tests the best",
    )
    args = parser.parse_args(argv)
    try:
        path, record = run_cell(
            task=args.task,
            method=args.method,
            setting=args.setting,
            test_setting=args.test_setting,
            imagery=args.imagery,
            steps=args.steps,
            batch_size=args.batch_size,
            lr=args.lr,
            episodes=args.episodes,
            val_every=args.val_every,
            val_episodes=args.val_episodes,
            overlays=args.config,
            config_dir=args.configs,
            results=args.results,
            logs=args.logs,
            force=args.force,
            eval_workers=args.eval_workers,
            device=args.device,
            fit_only=args.fit_only,
            table=Path("results"),
        )
    except (CellError, FileNotFoundError, UnwritableError, UntrustedCheckpointError) as error:
        print(f"nerf-transporter run-cell: {error}", file=sys.stderr)
        return 2
    if args.fit_only and path.is_dir():  # the run folder of the fit
        print(f"fit done: {path}; validate and test it with the same command without --fit-only")
        return 0
    if record is None:
        print(
            f"{path} holds this cell under the same protocol: skipped (--force measures it again)"
        )
        return 0
    if record["errors"]:
        print(
            f"nerf-transporter run-cell: no cell written to {path}: {erred_episodes_text(record)}\n"
            "Fix the cause and run the same command again (the fit is kept).",
            file=sys.stderr,
        )
        return 1
    print(f"{path}: {cell(record)}, checkpoint at step {record['checkpoint']['step']}")
    return 0
