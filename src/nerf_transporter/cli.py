"""nerf-transporter: training sub-commands (fit, validate, test, predict) run LightningCLI;
the others (oracle, generate, dataset-info, report, ...) are tools around it."""

from __future__ import annotations

import contextlib
import importlib
import itertools
import logging
import os
import pickle
import re
import shutil
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from nerf_transporter.atomic import unwritable_reason

# sub-command -> ("module:function", one-line help). Each function takes argv and returns an exit code.
TOOLS: dict[str, tuple[str, str]] = {
    "oracle": (
        "nerf_transporter.sim.oracle_cli:main",
        "run oracle episodes, print the success rate",
    ),
    "generate": (
        "nerf_transporter.data.generate:main",
        "oracle demonstrations -> episodes on disk",
    ),
    "dataset-info": (
        "nerf_transporter.data.info:main",
        "episodes, seeds, imagery quality (--verify)",
    ),
    "report": ("nerf_transporter.experiments.report:main", "results table (markdown or --csv)"),
    "try": (
        "nerf_transporter.experiments.pretrained:try_main",
        "run a shipped pretrained policy on a few test episodes, write videos",
    ),
    "export-pretrained": (
        "nerf_transporter.experiments.pretrained:export_main",
        "reduce a trained checkpoint to a shipped pretrained policy",
    ),
    "run-cell": (
        "nerf_transporter.experiments.run_cell:main",
        "one cell of the results table: fit, pick by validation, test, write its JSON",
    ),
    "cache-imagery": (
        "nerf_transporter.experiments.cache_imagery:main",
        "build a split's evaluation imagery (NeRF fits) into the cache before its episodes run",
    ),
    "failures": (
        "nerf_transporter.experiments.failures:main",
        "why the cells' test episodes failed: pick, aim (position / tilt / yaw) or settling",
    ),
    "compare-cells": (
        "nerf_transporter.experiments.compare:main",
        "cells tested alike (trained in either setting), paired on common seeds: McNemar p",
    ),
    "evaluate-checkpoints": (
        "nerf_transporter.experiments.checkpoints:main",
        "closed-loop success of every checkpoint of a run, to pick the one to test",
    ),
}


# (source, target) of LightningCLI's argument links: what the model must share with the data is
# stated once, under `data`; a DataModule without the source leaves the model's value as configured.
# (gt_state_mlp's state length needs no link: it asks the trainer's DataModule, `state_dim`.)
LINKS: tuple[tuple[str, str], ...] = (
    ("data.init_args.pixel_size", "model.init_args.pixel_size"),
    ("data.init_args.n_rotations", "model.init_args.n_rotations"),
)

LOG_ROOT = Path("logs")
VERSION_FOLDER = re.compile(r"version_(\d+)")

# Sub-commands handed to LightningCLI (also what the `lightning` console script runs).
LIGHTNING_COMMANDS: dict[str, str] = {
    "fit": "train a method (LightningCLI; e.g. --config configs/block_insertion.yaml)",
    "validate": "validation losses of a checkpoint (LightningCLI)",
    "test": "closed-loop evaluation of a checkpoint (LightningCLI)",
    "predict": "predictions of a checkpoint (LightningCLI)",
}


def _usage() -> str:
    commands = list(LIGHTNING_COMMANDS.items())
    commands += [(name, help_text) for name, (_, help_text) in sorted(TOOLS.items())]
    width = max(len(name) for name, _ in commands) + 2
    lines = ["usage: nerf-transporter <command> [options]", "", "commands:"]
    lines += [f"  {name:<{width}}{help_text}" for name, help_text in commands]
    lines.append("\nRun `nerf-transporter <command> --help` for the options of one command.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    command, rest = argv[0], argv[1:]
    if command in LIGHTNING_COMMANDS:
        return lightning_main(argv)
    if command not in TOOLS:
        print(f"nerf-transporter: unknown command {command!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, function_name = TOOLS[command][0].split(":")
    function = getattr(importlib.import_module(module_name), function_name)
    try:
        return int(function(rest) or 0)
    except BrokenPipeError:  # the reader left (`| head`): stop quietly, as a pipeline expects
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


def run_name(model: Any, datamodule: Any) -> str:
    """`<task>/<method>` (task suffixed with its setting unless Normal): the TensorBoard run name."""
    task = str(getattr(datamodule, "task", None) or "unknown-task")
    setting = getattr(datamodule, "setting", "normal")
    if setting and setting != "normal":
        task = f"{task}-{setting}"
    return f"{task}/{getattr(model, 'name', type(model).__name__.lower())}"


def _version(path: Path) -> int | None:
    match = VERSION_FOLDER.fullmatch(path.name)
    return int(match.group(1)) if match else None


def claim_version(runs: Path) -> int:
    """Create and return the next free `version_N` under `runs`. mkdir is atomic, so two runs
    started together never share a folder (one of them takes the next number)."""
    runs.mkdir(parents=True, exist_ok=True)
    taken = [number for path in runs.iterdir() if (number := _version(path)) is not None]
    version = max(taken, default=-1) + 1
    while True:
        try:
            (runs / f"version_{version}").mkdir()
            return version
        except FileExistsError:
            version += 1


class NoRunToResumeError(FileNotFoundError):
    """`--ckpt_path last` where the task and method have no run with a readable checkpoint."""


class RunArgumentError(ValueError):
    """An option with which `lightning fit|validate|test|predict` cannot run, found before any
    run folder is claimed (a checkpoint that is no readable file, no step to train, no episode to
    test, a folder that cannot be written)."""


def latest_checkpoint(runs: Path) -> Path:
    """The checkpoint to resume from: in the highest-numbered run under `runs` with a readable
    checkpoint, the one of the highest global step, whatever its name (`last.ckpt` lags behind
    where Lightning wrote `last-v1.ckpt` in a moved run folder) or time (a copy from another
    machine can give every file the same time); an unreadable one (partly written, e.g. on a
    full disk) is skipped with a warning."""
    from nerf_transporter.experiments.checkpoints import checkpoint_steps

    folders = list(runs.iterdir()) if runs.is_dir() else []
    numbered = [(number, path) for path in folders if (number := _version(path)) is not None]
    for _, path in sorted(numbered, reverse=True):
        if steps := checkpoint_steps(path / "checkpoints"):
            return steps[-1][1]
    raise NoRunToResumeError(
        f"--ckpt_path last: no earlier run to resume, no readable checkpoint under {runs}/"
        "version_N/checkpoints; start a new run without --ckpt_path"
    )


@contextlib.contextmanager
def removed_if_unused(claimed: list[Path]) -> Iterator[None]:
    """Where the block raises, remove the run folders in `claimed` that hold no checkpoint and no
    results file: a failed command leaves no `version_N` with nothing to resume or read."""
    try:
        yield
    except BaseException:
        from nerf_transporter.experiments.cells import TEST_RECORD_GLOB

        for folder in claimed:
            if not any(folder.rglob("*.ckpt")) and not any(folder.rglob(TEST_RECORD_GLOB)):
                shutil.rmtree(folder, ignore_errors=True)
        raise


def check_checkpoint_file(path: Path, weights_only: bool | None) -> None:
    """RunArgumentError where `path` is no checkpoint file that loads (a folder, missing,
    truncated); a checkpoint refused by `weights_only` raises `pickle.UnpicklingError`."""
    import torch

    if path.is_dir():
        raise RunArgumentError(f"--ckpt_path {path} is a folder, not a checkpoint file")
    if not path.is_file():
        raise RunArgumentError(f"--ckpt_path {path}: no such checkpoint file")
    try:
        torch.load(path, map_location="cpu", weights_only=weights_only, mmap=True)
    except pickle.UnpicklingError:
        raise
    except Exception as error:  # truncated, or not a checkpoint at all
        raise RunArgumentError(
            f"--ckpt_path {path} is not a readable checkpoint (partly written or not one): {error}"
        ) from error


def run_folder(checkpoint: str) -> Path | None:
    """The run folder (`.../version_N`) whose `checkpoints/` holds a local checkpoint, if any."""
    path = Path(checkpoint)
    if (
        path.is_file()
        and path.parent.name == "checkpoints"
        and _version(path.parent.parent) is not None
    ):
        return path.parent.parent
    return None


def build_cli(
    args: list[str] | None = None, run: bool = True, claimed: list[Path] | None = None
) -> Any:
    """LightningCLI: `model` is any `Method`, `data` any LightningDataModule; config files may
    build on others with `__include__` (`config_include`), the model takes its pixel size and
    rotation bins from the data (`LINKS`).

    Every trainer gets a `ClosedLoopTestCallback` besides the callbacks of the config, so `test`
    plays the test seeds closed loop (`--video DIR` records them); `cli.closed_loop_test` is that
    callback, its `record` the results of the test.

    Without an explicit `trainer.logger`, a run logs with TensorBoard to its own
    `logs/<task>/<method>/version_N` (claimed atomically) with checkpoints in its `checkpoints/`;
    `fit --ckpt_path last` resumes the latest run of that task and method in its folder, and
    `test`/`validate`/`predict` of a run's checkpoint log into that run. Configs are saved there
    without replacing one already present. Checkpoints load with `weights_only=True` unless
    `--weights_only false` is given. Before a run folder is claimed, the options are checked
    (`RunArgumentError`): `--ckpt_path` a checkpoint file that loads, at least one step to fit and
    one episode to test, the run folder and `--video` writable. The run folders claimed are
    appended to `claimed` where given. Returns the `LightningCLI` object.
    """
    import lightning.pytorch as pl
    from lightning.fabric.utilities.rank_zero import rank_zero_only
    from lightning.pytorch.cli import LightningArgumentParser, LightningCLI, SaveConfigCallback
    from lightning.pytorch.loggers import TensorBoardLogger

    from nerf_transporter import config_include
    from nerf_transporter.evaluation.testing import ClosedLoopTestCallback
    from nerf_transporter.methods import Method

    quiet_lightning()
    test_callback = ClosedLoopTestCallback()

    class RunConfigCallback(SaveConfigCallback):
        """Saves the resolved config in the run folder as `config.yaml`, or, where a resumed fit or
        a test of the run's checkpoint finds one, as `config-<stage>[-N].yaml` beside it."""

        def setup(self, trainer: pl.Trainer, pl_module: pl.LightningModule, stage: str) -> None:
            if not self.already_saved:
                folder = Path(trainer.log_dir or ".")  # a collective call under DDP
                self.config_filename = free_name(folder, "config", getattr(stage, "value", stage))
            super().setup(trainer, pl_module, stage)

    class NerfTransporterCLI(LightningCLI):
        closed_loop_test = test_callback  # in every trainer; its `record` after `test`

        def add_arguments_to_parser(self, parser: LightningArgumentParser) -> None:
            """The model's pixel size and rotation bins are the data's (LINKS)."""
            for source, target in LINKS:
                parser.link_arguments(source, target)

        def _prepare_subcommand_parser(self, klass: type, subcommand: str, **kwargs: Any) -> Any:
            parser = super()._prepare_subcommand_parser(klass, subcommand, **kwargs)
            if "weights_only" in self._subcommand_method_arguments[subcommand]:
                parser.set_defaults({"weights_only": True})  # never unpickle code from a checkpoint
            if subcommand == "test":
                # the callback prints the rounded rate with its interval; Lightning's table would
                # repeat it with float32 digits
                parser.set_defaults({"verbose": False})
                parser.add_argument(
                    "--video",
                    type=str | None,
                    default=None,
                    help="write one mp4 per test episode into this folder, captioned, with the "
                    "chosen pick and place drawn in (a JSON sidecar holds the caption and outcome)",
                )
            return parser

        def before_test(self) -> None:
            self.closed_loop_test.video_dir = self._get(self.config, "video")

        def instantiate_trainer(self, **kwargs: Any) -> pl.Trainer:
            if self.subcommand is not None:
                self._check_arguments()
            logger = self._get(self.config_init, "trainer", default={}).get("logger")
            if logger is None or logger is True:
                kwargs["logger"] = self._run_logger()
            return super().instantiate_trainer(**kwargs)

        def _parse_ckpt_path(self) -> None:
            """A `--ckpt_path` file is checked (`check_checkpoint_file`) before Lightning reads
            the hyper-parameters in it."""
            subcommand = self.config.get("subcommand")
            ckpt_path = self.config[subcommand].get("ckpt_path") if subcommand else None
            named = ckpt_path in ("last", "best", "hpc") or str(ckpt_path).startswith("registry")
            if ckpt_path is not None and not named and "://" not in str(ckpt_path):
                weights_only = self.config[subcommand].get("weights_only")
                check_checkpoint_file(Path(ckpt_path), weights_only)
            from nerf_transporter.methods import TEST_TIME_OPTIONS

            model = self.config[subcommand].get("model") if subcommand else None
            init_args = getattr(model, "init_args", None) or {}
            chosen = {key: init_args[key] for key in TEST_TIME_OPTIONS if key in init_args}
            super()._parse_ckpt_path()
            # a test-time option (mira's view choice) is the config's, not the checkpoint's
            model = self.config[subcommand].get("model") if subcommand else None
            for key, value in chosen.items():
                model.init_args[key] = value
                if getattr(model, "dict_kwargs", None):
                    model.dict_kwargs.pop(key, None)

        def _check_arguments(self) -> None:
            """RunArgumentError for options the run would fail on after claiming its folder."""
            trainer = self._get(self.config_init, "trainer", default={})
            steps = trainer.get("max_steps") if self.subcommand == "fit" else None
            if steps is not None and steps != -1 and steps < 1:
                raise RunArgumentError(
                    f"--trainer.max_steps {steps}: a fit needs at least one training step "
                    "(-1: as many as max_epochs allows)"
                )
            episodes = getattr(self.datamodule, "test_episodes", None)
            if self.subcommand == "test" and episodes is not None and episodes < 1:
                raise RunArgumentError(
                    f"--data.init_args.test_episodes {episodes}: a test needs at least one episode"
                )
            video = self._get(self.config, "video") if self.subcommand == "test" else None
            if video and (reason := unwritable_reason(video)):
                raise RunArgumentError(f"--video {video} cannot be written: {reason}")

        def _run_logger(self) -> TensorBoardLogger:
            runs = LOG_ROOT / run_name(self.model, self.datamodule)
            ckpt_path = self._get(self.config_init, "ckpt_path")
            folder = None
            if self.subcommand == "fit" and ckpt_path == "last":
                checkpoint = latest_checkpoint(runs)
                self.config_init[self.subcommand]["ckpt_path"] = str(checkpoint)
                folder = checkpoint.parent.parent
            elif self.subcommand is not None and ckpt_path:
                folder = run_folder(str(ckpt_path))
            if self.subcommand is not None and (reason := unwritable_reason(folder or runs)):
                raise RunArgumentError(f"cannot write the run folder {folder or runs}: {reason}")
            if folder is not None:
                return TensorBoardLogger(
                    save_dir=folder.parent, name="", version=folder.name, default_hp_metric=False
                )
            # other DDP processes leave the folder to rank 0 (Lightning broadcasts its log_dir);
            # a CLI built without running (run=False) claims nothing
            claim = self.subcommand is not None and rank_zero_only.rank == 0
            version = claim_version(runs) if claim else None
            if version is not None and claimed is not None:
                claimed.append(runs / f"version_{version}")
            return TensorBoardLogger(
                save_dir=LOG_ROOT,
                name=str(runs.relative_to(LOG_ROOT)),
                version=version,
                default_hp_metric=False,
            )

    return NerfTransporterCLI(
        Method,
        pl.LightningDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        parser_kwargs={"parser_mode": config_include.register()},
        save_config_callback=RunConfigCallback,
        save_config_kwargs={"overwrite": False},
        trainer_defaults=trainer_defaults(test_callback),
        args=args,
        run=run,
    )


def trainer_defaults(test_callback: Any) -> dict[str, Any]:
    """Defaults under a config's trainer keys: the closed-loop test callback (appended to a config's
    callbacks) and, where stderr is not a terminal (a log file), progress as lines instead of
    Lightning's bar (`progress.LineProgress`; a config's `enable_progress_bar` still wins)."""
    if sys.stderr.isatty():
        return {"callbacks": [test_callback]}
    from nerf_transporter.progress import LineProgress

    return {"callbacks": [test_callback, LineProgress()], "enable_progress_bar": False}


def free_name(folder: Path, stem: str, stage: str) -> str:
    """`<stem>.yaml` if free in `folder`, else `<stem>-<stage>.yaml`, `<stem>-<stage>-2.yaml`, ..."""
    names = itertools.chain(
        [f"{stem}.yaml", f"{stem}-{stage}.yaml"],
        (f"{stem}-{stage}-{number}.yaml" for number in itertools.count(2)),
    )
    return next(name for name in names if not (folder / name).exists())


def fit_summary(trainer: Any) -> str:
    """Where a finished fit left its run, its best checkpoint and the command that tests it."""
    from lightning.pytorch.cli import SaveConfigCallback

    from nerf_transporter.evaluation.callback import SuccessRateCallback
    from nerf_transporter.experiments.checkpoints import best_record, validation_records

    logger = trainer.logger  # its own log_dir: Trainer.log_dir is a collective call under DDP
    folder = Path(getattr(logger, "log_dir", None) or trainer.default_root_dir)
    lines = [f"run folder: {folder}"]
    checkpoint = trainer.checkpoint_callback
    validation = [c for c in trainer.callbacks if isinstance(c, SuccessRateCallback)]
    folder_of_checkpoints = getattr(checkpoint, "dirpath", None)
    record = None
    if validation and folder_of_checkpoints and Path(folder_of_checkpoints).is_dir():
        # the rule run-cell and evaluate-checkpoints choose by: among equals the later step
        records = validation_records(Path(folder_of_checkpoints), validation[0].episodes)
        record = best_record(records)
    if record is not None:
        best = record["checkpoint"]
        chosen = (
            f" (validation success {record['successes']}/{record['episodes']} at step "
            f"{record['global_step']}, the latest of the best)"
        )
    else:
        best = getattr(checkpoint, "best_model_path", "") or getattr(
            checkpoint, "last_model_path", ""
        )
        score = getattr(checkpoint, "best_model_score", None)
        monitor = getattr(checkpoint, "monitor", None)
        chosen = f" ({monitor} {float(score):.2f})" if monitor and score is not None else ""
    if best:
        lines.append(f"best checkpoint{chosen}: {best}")
        saved = [c for c in trainer.callbacks if isinstance(c, SaveConfigCallback)]
        config = folder / saved[0].config_filename if saved else Path("<config>")
        lines.append(f"next: lightning test --config {config} --ckpt_path {best}")
    return "\n".join(lines)


def quiet_lightning() -> None:
    """Drop Lightning's advertising tips and warnings that do not apply to this project's runs."""

    class NoTips(logging.Filter):
        def filter(self, record: logging.LogRecord) -> bool:
            return "Tip:" not in record.getMessage()

    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.fabric.utilities.rank_zero"):
        logger = logging.getLogger(name)
        if not any(isinstance(f, NoTips) for f in logger.filters):
            logger.addFilter(NoTips())
    # Lightning's own use of a torch API it deprecated; nothing a user can change
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)")
    # in-memory demonstrations: loader workers do not pay on a CPU (set data.num_workers on a GPU)
    warnings.filterwarnings("ignore", message=r".*does not have many workers")
    # validation losses are optional (data.n_val_demos); success is measured closed loop
    warnings.filterwarnings("ignore", message=r".*but have no `val_dataloader`")
    warnings.filterwarnings("ignore", message=r"Total length of `list` across ranks is zero")
    # RavensDataModule resumes mid-epoch itself (its sampler skips the batches already trained)
    warnings.filterwarnings(
        "ignore", message=r"You're resuming from a checkpoint that ended before"
    )


def lightning_main(args: list[str] | None = None) -> int:
    """The `lightning` console script: `lightning fit|validate|test|predict ...`.

    Exits 1 when a closed-loop test had erred episodes (their seeds are listed); 2 when
    `--ckpt_path last` finds no run to resume, an option cannot run (`RunArgumentError`) or a
    checkpoint holds more than weights. A failed command removes the run folder it claimed
    where that holds no checkpoint and no results file (`removed_if_unused`)."""
    from nerf_transporter.evaluation.testing import erred_seeds_line

    claimed: list[Path] = []
    try:
        with removed_if_unused(claimed):
            cli = build_cli(args, claimed=claimed)
    except (NoRunToResumeError, RunArgumentError) as error:
        print(f"lightning: {error}", file=sys.stderr)
        return 2
    except pickle.UnpicklingError as error:
        print(
            "lightning: refused to load the checkpoint: it holds objects other than tensors and "
            "plain values, which could run code (loaded with weights_only=True; pass "
            f"--weights_only false only for a checkpoint you trust):\n  {error}",
            file=sys.stderr,
        )
        return 2
    if cli.subcommand == "fit" and cli.trainer.is_global_zero:
        print(fit_summary(cli.trainer))
    record = cli.closed_loop_test.record
    if record is not None and record["errors"]:
        print(f"lightning test: {erred_seeds_line(record)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
