"""The LightningCLI of `lightning fit|validate|test` (`nerf-transporter fit|...`): any
method on any DataModule, configs that include others, the closed-loop test callback in every
trainer, each run in a run folder of its own (`experiments.runs`), the options checked before one is
claimed."""

from __future__ import annotations

import itertools
import logging
import pickle
import sys
import traceback
import warnings
from pathlib import Path
from typing import Any

from nerf_transporter.atomic import UnwritableError, unwritable_reason
from nerf_transporter.experiments.runs import (
    LOG_ROOT,
    NoRunToResumeError,
    claim_version,
    latest_checkpoint,
    removed_if_unused,
    run_folder,
    run_name,
)

# (source, target) of LightningCLI's argument links: what the model must share with the data is
# stated once, under `data`; a DataModule without the source leaves the model's value as configured.
# (gt_state_mlp's state length needs no link: it asks the trainer's DataModule, `state_dim`.)
LINKS: tuple[tuple[str, str], ...] = (
    ("data.init_args.pixel_size", "model.init_args.pixel_size"),
    ("data.init_args.n_rotations", "model.init_args.n_rotations"),
)


class RunArgumentError(ValueError):
    """An option with which `lightning fit|validate|test` cannot run, found before any
    run folder is claimed (a checkpoint that is no readable file, no step to train, no episode to
    test, a folder that cannot be written)."""


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


# why `lightning predict` is not offered
NO_PREDICT = (
    "a policy here is judged by what it does in the simulator, not by predictions on a data "
    "set: run `lightning test --config <config> --ckpt_path <checkpoint>` (closed-loop test "
    "episodes, with --video to see each action) or `nerf-transporter evaluate-checkpoints <run>`"
)


def refused_argument(error: BaseException) -> str | None:
    """`<group>.init_args of <class>: <message>` of the ValueError a model or DataModule `__init__`
    raised behind `error` (jsonargparse wraps it in its report of the union of types it tried),
    None where the error did not come from one."""
    import lightning.pytorch as pl

    seen = []
    while error is not None and error not in seen:
        seen.append(error)
        error = error.__cause__ or error.__context__
    for cause in reversed(seen):
        if not isinstance(cause, ValueError):
            continue
        for frame, _ in traceback.walk_tb(cause.__traceback__):
            owner = frame.f_locals.get("self")
            if frame.f_code.co_name == "__init__" and isinstance(
                owner, pl.LightningModule | pl.LightningDataModule
            ):
                group = "model" if isinstance(owner, pl.LightningModule) else "data"
                return f"{group}.init_args of {type(owner).__name__}: {cause}"
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
    `test`/`validate` of a run's checkpoint log into that run. Configs are saved there
    without replacing one already present. Checkpoints load with `weights_only=True` unless
    `--weights_only false` is given. Before a run folder is claimed, the options are checked
    (`RunArgumentError`): `--ckpt_path` a checkpoint file that loads and whose hyper-parameters
    name only this package's classes (nothing else it names is imported), at least one step to fit
    and one episode to test, the run folder and `--video` writable. The run folders claimed are
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

        @staticmethod
        def subcommands() -> dict[str, set[str]]:
            """Lightning's sub-commands but `predict` (`NO_PREDICT`)."""
            return {
                name: keys for name, keys in LightningCLI.subcommands().items() if name != "predict"
            }

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
            """A `--ckpt_path` file is checked (`check_checkpoint_file`), and the classes its
            hyper-parameters name (`check_checkpoint_classes`: jsonargparse would import them),
            before Lightning reads the hyper-parameters in it."""
            from nerf_transporter.experiments.checkpoints import (
                UntrustedCheckpointError,
                check_checkpoint_classes,
            )

            subcommand = self.config.get("subcommand")
            ckpt_path = self.config[subcommand].get("ckpt_path") if subcommand else None
            named = ckpt_path in ("last", "best", "hpc") or str(ckpt_path).startswith("registry")
            if ckpt_path is not None and not named and "://" not in str(ckpt_path):
                weights_only = self.config[subcommand].get("weights_only")
                check_checkpoint_file(Path(ckpt_path), weights_only)
            if ckpt_path and Path(ckpt_path).is_file():  # the file Lightning reads them from
                try:
                    check_checkpoint_classes(ckpt_path, keys=("hyper_parameters",))
                except UntrustedCheckpointError as error:
                    raise RunArgumentError(f"--ckpt_path {error}") from None
            from nerf_transporter.methods import TEST_TIME_OPTIONS

            model = self.config[subcommand].get("model") if subcommand else None
            init_args = getattr(model, "init_args", None) or {}
            chosen = {key: init_args[key] for key in TEST_TIME_OPTIONS if key in init_args}
            super()._parse_ckpt_path()
            if ckpt_path and Path(ckpt_path).is_file():
                self._use_trained_imagery(subcommand, Path(ckpt_path))
            # a test-time option (mira's view choice) is the config's, not the checkpoint's
            model = self.config[subcommand].get("model") if subcommand else None
            for key, value in chosen.items():
                model.init_args[key] = value
                if getattr(model, "dict_kwargs", None):
                    model.dict_kwargs.pop(key, None)

        def _use_trained_imagery(self, subcommand: str, ckpt_path: Path) -> None:
            """The data's NeRF imagery is the one the checkpoint was trained on
            (`RavensDataModule.trained_imagery`), as Lightning takes the model's hyper-parameters
            from it: a test, or a resumed fit, of a policy is on the imagery it learned."""
            import torch

            from nerf_transporter.data.datamodule import RavensDataModule

            checkpoint = torch.load(ckpt_path, map_location="cpu", weights_only=True, mmap=True)
            saved = checkpoint.get("datamodule_hyper_parameters", {})
            data = self.config[subcommand].get("data")
            ravens = f"{RavensDataModule.__module__}.{RavensDataModule.__qualname__}"
            if saved.get("_class_path") != ravens or getattr(data, "class_path", None) != ravens:
                return
            data.init_args.imagery_config = RavensDataModule.trained_imagery(
                saved.get("imagery_config")
            )

        def instantiate_classes(self) -> None:
            """A model or data argument its class refuses (a ValueError of its `__init__`, which
            jsonargparse reports inside its own) is a RunArgumentError naming the class and the
            problem."""
            try:
                super().instantiate_classes()
            except ValueError as error:
                refused = refused_argument(error)
                if refused is None:
                    raise
                raise RunArgumentError(refused) from error

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


def main(args: list[str] | None = None) -> int:
    """The `lightning` console script: `lightning fit|validate|test ...`.

    Exits 1 when a closed-loop test had erred episodes (their seeds are listed); 2 when
    `--ckpt_path last` finds no run to resume, an option cannot run (`RunArgumentError`), a folder
    to write (the data's) cannot be written, a checkpoint holds more than weights or an episode of
    the data is damaged, edited or of another configuration. A failed command removes the run
    folder it claimed where that holds no checkpoint and no results file (`removed_if_unused`)."""
    from nerf_transporter.data.episode import CorruptEpisodeError, DatasetConfigMismatchError
    from nerf_transporter.evaluation.testing import erred_seeds_line

    command = (sys.argv[1:] if args is None else args)[:1]
    if command == ["predict"]:
        print(f"lightning predict: {NO_PREDICT}", file=sys.stderr)
        return 2
    claimed: list[Path] = []
    try:
        with removed_if_unused(claimed):
            cli = build_cli(args, claimed=claimed)
    except (
        NoRunToResumeError,
        RunArgumentError,
        UnwritableError,
        CorruptEpisodeError,
        DatasetConfigMismatchError,
    ) as error:
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
