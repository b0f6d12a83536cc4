"""`nerf-transporter evaluate-checkpoints <run dir> --split validation --episodes N`.

Checkpoint selection as the Transporter authors did it: save checkpoints at fixed iterations, run every
one of them closed loop on the validation seeds, and test the best. Each checkpoint's figures go to
`<run dir>/evaluation/<checkpoint>-<split>-<setting>.json` (`-2`, `-3`, ... when evaluated again:
nothing is replaced); the command prints a table and the `lightning test` command for the best
checkpoint, chosen among the evaluations without erred episodes. The episodes run in `--eval-workers`
processes (default: one per available core). Models and DataModules are rebuilt
from the hyper-parameters inside the checkpoints (LightningCLI stores the method's class path
there), and checkpoints are read with `weights_only=True`; an unreadable checkpoint is skipped with
a warning. A checkpoint whose hyper-parameters name any other class than this package's methods and
DataModule is refused before anything is imported (`check_checkpoint_classes`), as is a run folder
whose `evaluation/` (or `--video` folder) cannot be written, before the first episode.
"""

from __future__ import annotations

import argparse
import functools
import json
import logging
import math
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import torch

from nerf_transporter.atomic import check_writable, write_new_json
from nerf_transporter.console import HelpFormatter
from nerf_transporter.data.generate import add_imagery_option_argument
from nerf_transporter.data.observation import IMAGERY_KINDS
from nerf_transporter.evaluation.metrics import cell
from nerf_transporter.evaluation.rollout import DEFAULT_CACHE_DIR, Evaluators
from nerf_transporter.evaluation.testing import checkpoint_step, evaluate_policy
from nerf_transporter.evaluation.view_search import view_search_text
from nerf_transporter.methods.mira import VIEW_CHOICES
from nerf_transporter.provenance import read_segments
from nerf_transporter.splits import split_seed

log = logging.getLogger(__name__)


# under a run's evaluation folder: the episodes of evaluations under way (`evaluation.journal`)
JOURNALS = ".journals"
# the hyper-parameters a checkpoint may hold: the method's (what `lightning --ckpt_path` reads) and
# the DataModule's
HYPER_PARAMETER_KEYS = ("hyper_parameters", "datamodule_hyper_parameters")
# the instantiator LightningCLI stores beside a class path (the only one a checkpoint may name)
LIGHTNING_INSTANTIATOR = "lightning.pytorch.cli.instantiate_module"


class UntrustedCheckpointError(ValueError):
    """A checkpoint whose hyper-parameters name code other than this package's methods and
    DataModule: building what they name would import that code."""


def trusted_class_paths() -> frozenset[str]:
    """The class paths a checkpoint may name: this package's methods and its DataModule, by their
    module, by the package that exports them and by their bare name (how LightningCLI and a config
    write them)."""
    from nerf_transporter.data.datamodule import RavensDataModule
    from nerf_transporter.methods import METHODS

    paths = {f"nerf_transporter.methods.{cls.__name__}" for cls in METHODS.values()}
    for cls in (*METHODS.values(), RavensDataModule):
        paths |= {cls.__name__, f"{cls.__module__}.{cls.__qualname__}"}
    return frozenset(paths)


def _named_classes(value: Any, where: str) -> Iterator[tuple[str, Any]]:
    """(where, value) of every class path and instantiator in nested hyper-parameters."""
    if isinstance(value, Mapping):
        for key, item in value.items():
            place = f"{where}.{key}"
            if key in ("_class_path", "class_path", "_instantiator"):
                yield place, item
            else:
                yield from _named_classes(item, place)
    elif isinstance(value, list | tuple):
        for index, item in enumerate(value):
            yield from _named_classes(item, f"{where}[{index}]")


def check_checkpoint_classes(
    path: str | Path, keys: tuple[str, ...] = HYPER_PARAMETER_KEYS
) -> None:
    """UntrustedCheckpointError where the hyper-parameters (`keys`) of the checkpoint at `path`
    name a class other than this package's methods and DataModule, or an instantiator other than
    LightningCLI's. Only strings are compared: nothing the checkpoint names is imported. The file
    is read with `weights_only=True` (a checkpoint holding other objects raises
    `pickle.UnpicklingError`)."""
    checkpoint = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    trusted = trusted_class_paths()
    for key in keys:
        hyper_parameters = checkpoint.get(key) if isinstance(checkpoint, Mapping) else None
        if hyper_parameters is not None and not isinstance(hyper_parameters, Mapping):
            raise UntrustedCheckpointError(
                f"{path}: {key} is {type(hyper_parameters).__name__}, not the hyper-parameters "
                "of a lightning fit run"
            )
        for where, named in _named_classes(hyper_parameters or {}, key):
            allowed = {LIGHTNING_INSTANTIATOR} if where.endswith("._instantiator") else trusted
            if not isinstance(named, str) or named not in allowed:
                raise UntrustedCheckpointError(
                    f"{path} names {named!r} in {where}, not one of this package's methods or "
                    "its DataModule: refused, nothing it names was imported (only checkpoints of "
                    "`lightning fit` runs of this package load)"
                )


class NoLoadableCheckpointError(FileNotFoundError):
    """None of the checkpoints to evaluate could be loaded: nothing was evaluated (as where a run
    holds no readable checkpoint file)."""


def checkpoint_steps(run_dir: Path) -> list[tuple[int, Path]]:
    """(global step, path) of every readable checkpoint under `run_dir`, by step; a copy of a step
    (`last.ckpt`, `last-v1.ckpt`) is left out, an unreadable file is skipped with a warning."""
    by_step: dict[int, Path] = {}
    paths = sorted(run_dir.rglob("*.ckpt"), key=lambda p: (p.name.startswith("last"), str(p)))
    for path in paths:
        try:
            step = checkpoint_step(path)
        except Exception as error:  # truncated, not a checkpoint, or refused by weights_only
            log.warning("skipping unreadable checkpoint %s: %s", path, error)
            continue
        by_step.setdefault(step, path)
    return sorted(by_step.items())


def in_run(run_dir: Path, path: Path) -> Path:
    """`path`, or, where it is a bare file name that is not a file here, the run's one checkpoint
    of that name (`--checkpoint step006000.ckpt`)."""
    if path.is_file() or path.parent != Path("."):
        return path
    matches = list(run_dir.rglob(path.name))
    return matches[0] if len(matches) == 1 else path


def chosen_checkpoints(run_dir: Path, paths: list[Path]) -> list[tuple[int, Path]]:
    """(global step, path) of the named checkpoints of a run, by step; a file outside the run or
    unreadable is an error naming it (its evaluation would be filed with another run)."""
    chosen = set()
    for path in (in_run(run_dir, path) for path in paths):
        if not path.is_file() or not path.resolve().is_relative_to(run_dir.resolve()):
            raise FileNotFoundError(f"{path} is not a checkpoint file inside the run {run_dir}")
        try:
            chosen.add((checkpoint_step(path), path))
        except Exception as error:  # truncated, not a checkpoint, or refused by weights_only
            raise ValueError(f"{path} is not a readable checkpoint: {error}") from error
    return sorted(chosen)


def config_callbacks(config: dict[str, Any], name: str) -> list[dict[str, Any]]:
    """The `trainer.callbacks` entries of a resolved run config whose class is named `name`."""
    return [
        callback
        for callback in config.get("trainer", {}).get("callbacks") or []
        if str(callback.get("class_path", "")).rsplit(".", 1)[-1] == name
    ]


def validation_score(checkpoint: dict[str, Any]) -> float | None:
    """The closed-loop validation success a loaded checkpoint was saved with: its ModelCheckpoint's
    `eval/success_rate` score (not finite where that round had erred episodes); None without one."""
    for key, state in checkpoint.get("callbacks", {}).items():
        if key.startswith("ModelCheckpoint") and state.get("monitor") == "eval/success_rate":
            score = state.get("current_score")
            return None if score is None else float(score)
    return None


def evaluated_validation(
    run_dir: Path, checkpoint: Path, episodes: int, setting: str, view_choice: str = "max_logit"
) -> dict[str, Any] | None:
    """The first `evaluate_checkpoints` record of `checkpoint` in `run_dir/evaluation` on the first
    `episodes` validation seeds of `setting`, under the view choice `view_choice` (mira's; the
    other methods have none) and the training's imagery settings, or None."""
    for path in sorted((run_dir / "evaluation").glob(f"{checkpoint.stem}-validation-*.json")):
        record = json.loads(path.read_text())
        if (
            Path(record.get("checkpoint") or "").name == checkpoint.name
            and record.get("split") == "validation"
            and record.get("setting") == setting
            and record.get("episodes", 0) + record.get("errors", 0) == episodes
            and not record.get("imagery_options")  # an imagery candidate's, not the training's
            and record.get("test_time_options", {}).get("view_choice", "max_logit") == view_choice
        ):
            return record
    return None


def validation_records(
    run_dir: Path, episodes: int, setting: str | None = None, view_choice: str = "max_logit"
) -> list[dict[str, Any]]:
    """One record per checkpoint of the run (by step): the validation success ModelCheckpoint
    stored with it; `errors` is 1 where that round had erred episodes (stored as -inf). With
    `setting`, a checkpoint saved without a round (by a fit without closed-loop validation, e.g.
    on a machine without PyBullet) takes its `evaluated_validation` record (under `view_choice`)
    instead, if any."""
    records = []
    for step, path in checkpoint_steps(run_dir):
        rate = validation_score(torch.load(path, map_location="cpu", weights_only=True, mmap=True))
        evaluated = (
            evaluated_validation(run_dir, path, episodes, setting, view_choice)
            if rate is None and setting
            else None
        )
        if evaluated is not None:
            rate = evaluated["success_rate"] if not evaluated["errors"] else -math.inf
        if rate is None:
            continue  # saved without a validation round (e.g. by an interrupted fit)
        valid = math.isfinite(rate)
        successes = round(rate * episodes) if valid else None
        records.append(
            {
                "checkpoint": str(path),
                "global_step": step,
                "success_rate": successes / episodes if valid else None,
                "successes": successes,
                "episodes": episodes if valid else 0,
                "errors": 0 if valid else 1,
            }
        )
    return records


def load_checkpoint(
    path: Path, device: torch.device, **test_time_options: Any
) -> tuple[torch.nn.Module, object]:
    """(method, datamodule) rebuilt from a checkpoint written by a LightningCLI run, with the
    method's test-time options (`Method.test_time_options`, e.g. mira's `view_choice`) where given
    instead of the checkpoint's; ValueError for an option the method does not take. A checkpoint
    that names other classes is refused first (`check_checkpoint_classes`)."""
    from nerf_transporter.data.datamodule import RavensDataModule
    from nerf_transporter.methods import METHODS

    check_checkpoint_classes(path)
    hparams = torch.load(path, map_location="cpu", weights_only=True).get("hyper_parameters", {})
    class_name = str(hparams.get("_class_path", "")).rsplit(".", 1)[-1]
    classes = {cls.__name__: cls for cls in METHODS.values()}
    if class_name not in classes:
        raise ValueError(
            f"{path} does not name one of the methods ({', '.join(sorted(classes))}) in its "
            "hyper-parameters (_class_path); it was not written by a `lightning fit` run"
        )
    cls = classes[class_name]
    unknown = sorted(set(test_time_options) - set(cls.test_time_options))
    if unknown:
        raise ValueError(
            f"{path}: {cls.name} takes no test-time option {', '.join(unknown)} (its options: "
            f"{', '.join(cls.test_time_options) or 'none'})"
        )
    model = cls.load_from_checkpoint(
        path, map_location=device, weights_only=True, **test_time_options
    )
    datamodule = RavensDataModule.load_from_checkpoint(path, weights_only=True)
    return model.to(device).eval(), datamodule


def evaluate_checkpoints(
    run_dir: Path,
    split: str,
    episodes: int,
    *,
    imagery: str | None = None,
    setting: str | None = None,
    cache_dir: str | None = DEFAULT_CACHE_DIR,
    device: torch.device | None = None,
    progress: bool = True,
    workers: int | None = None,
    video_dir: Path | None = None,
    only: list[Path] | None = None,
    view_choice: str | None = None,
    imagery_options: dict[str, Any] | None = None,
) -> list[dict]:
    """Evaluate every checkpoint of a run (or the `only` ones) on the first `episodes` seeds of
    `split`, in `workers` worker processes (default: one per available core; 1: in this process);
    with `video_dir`, every episode is recorded under `<video_dir>/<checkpoint>/`; `view_choice`
    (mira) tests under that view-choice rule instead of the checkpoint's; `imagery_options`
    (`ImageryConfig` fields) fit the NeRF imagery with those settings instead of the training
    data's (an imagery candidate; the records are named with them).

    Before the first episode: a checkpoint naming other classes than this package's is refused
    (UntrustedCheckpointError), and the records' folder and `video_dir` must be writable
    (`atomic.UnwritableError`). Each record names the machines the run was fitted on
    (`machine.fit`) beside its own commit and test machine (`results_record`). Each checkpoint's
    finished episodes are journalled under `<run>/evaluation/.journals/` until its record is
    written, so an interrupted evaluation resumes (`evaluation.journal`). A checkpoint that
    cannot be loaded is skipped with a warning; NoLoadableCheckpointError, naming each with its
    reason, where none could be."""
    checkpoints = checkpoint_steps(run_dir) if only is None else chosen_checkpoints(run_dir, only)
    if not checkpoints:
        raise FileNotFoundError(f"no readable .ckpt files under {run_dir}")
    for _, path in checkpoints:
        check_checkpoint_classes(path)
    check_writable("the evaluation records' folder", run_dir / "evaluation")
    if video_dir is not None:
        check_writable("--video", video_dir)
    device = device or torch.device("cuda" if torch.cuda.is_available() else "cpu")
    seeds = [split_seed(split, index) for index in range(episodes)]
    options = {} if view_choice is None else {"view_choice": view_choice}
    # the machines the run was fitted on (run-cell's fits; none recorded for a plain `lightning
    # fit`), beside the record's own (the one testing it)
    fitted_on = [segment["machine"] for segment in read_segments(run_dir)]
    # records are named with what was asked beyond the training's: imagery, view choice, options
    record_suffix = "".join(f"-{choice}" for choice in (imagery, view_choice) if choice)
    record_suffix += imagery_options_suffix(imagery_options)
    records, unloadable = [], []
    with Evaluators() as evaluators:
        for step, path in checkpoints:
            try:
                model, datamodule = load_checkpoint(path, device, **options)
            except Exception as error:  # a checkpoint of another program, or damaged past its step
                log.warning("skipping checkpoint %s that cannot be loaded: %s", path, error)
                unloadable.append(f"{path} ({error})")
                continue
            record = evaluate_policy(
                model,
                datamodule,
                seeds,
                split=split,
                setting=setting,
                imagery=imagery,
                imagery_options=imagery_options,
                cache_dir=cache_dir,
                workers=workers,
                checkpoint=str(path),
                global_step=step,
                progress=progress,
                desc=path.name,
                video_dir=video_dir / path.stem if video_dir else None,
                evaluators=evaluators,
                journal_dir=run_dir / "evaluation" / JOURNALS,
                keep=functools.partial(
                    keep_record, run_dir, path, split, fitted_on, suffix=record_suffix
                ),
            )
            records.append(record)
    if not records:
        raise NoLoadableCheckpointError(
            f"none of the {len(unloadable)} checkpoints of {run_dir} could be loaded, nothing was "
            "evaluated: " + "; ".join(unloadable)
        )
    return records


def keep_record(
    run_dir: Path,
    checkpoint: Path,
    split: str,
    fitted_on: list[dict[str, Any]],
    record: dict[str, Any],
    *,
    suffix: str,
) -> None:
    """Write a checkpoint's evaluation record, naming the machines its run was fitted on, as
    `<run>/evaluation/<checkpoint stem>-<split>-<setting><suffix>.json` (never replacing one)."""
    record["machine"] = {"fit": fitted_on, **record["machine"]}
    stem = f"{checkpoint.stem}-{split}-{record['setting']}{suffix}"
    write_new_json(run_dir / "evaluation", stem, record)


def imagery_options_suffix(imagery_options: dict[str, Any] | None) -> str:
    """`-<key><value>` for each imagery option, sorted: how records and caches of an imagery
    candidate are named."""
    return "".join(f"-{key}{value}" for key, value in sorted((imagery_options or {}).items()))


def best_record(records: list[dict]) -> dict | None:
    """Highest success rate among the evaluations without erred episodes; among equals the latest
    checkpoint. None when every evaluation had errors."""
    valid = [record for record in records if not record["errors"] and record["episodes"]]
    if not valid:
        return None
    return max(valid, key=lambda record: (record["success_rate"], record["global_step"]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter evaluate-checkpoints",
        description="Closed-loop success of every checkpoint of a run (e.g. "
        "logs/block-insertion/mira/version_0) on validation seeds, to pick the one to test. "
        "Interrupted, the same command resumes from the episodes already finished.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("run_dir", type=Path, help="a run's log directory (searched for *.ckpt)")
    parser.add_argument(
        "--split", choices=("validation", "test"), default="validation", help="seed range"
    )
    parser.add_argument("--episodes", type=int, default=10, help="episodes per checkpoint")
    parser.add_argument(
        "--checkpoint",
        type=Path,
        action="append",
        help="evaluate only this checkpoint of the run, a path or its file name "
        "(repeatable; default: every one)",
    )
    parser.add_argument(
        "--imagery",
        choices=IMAGERY_KINDS,
        help="default: as in training; where given, the records are named with it",
    )
    parser.add_argument("--setting", help="default: the training setting")
    parser.add_argument("--cache-dir", default=DEFAULT_CACHE_DIR, help="imagery cache")
    parser.add_argument("--device", default=None, help="torch device (default: cuda if present)")
    parser.add_argument(
        "--eval-workers",
        type=int,
        default=None,
        help="processes running the episodes (default: one per available core; 1: no workers)",
    )
    parser.add_argument(
        "--video",
        type=Path,
        default=None,
        help="write one captioned mp4 per episode into <video>/<checkpoint>/",
    )
    parser.add_argument(
        "--view-choice",
        choices=VIEW_CHOICES,
        default=None,
        help="mira: test under this view-choice rule instead of the checkpoint's (max_logit: the "
        "view with the highest raw logit; view_softmax: MIRA's, each view's own softmax); the "
        "records are named with it",
    )
    add_imagery_option_argument(
        parser,
        "fit the NeRF imagery with this setting (an ImageryConfig field, as `generate "
        "--imagery-option`) instead of the training data's, to test a policy on an imagery "
        "candidate (repeatable); the records are named with them",
    )
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    if args.eval_workers is not None and args.eval_workers < 1:
        parser.error("--eval-workers must be >= 1")
    try:
        records = evaluate_checkpoints(
            args.run_dir,
            args.split,
            args.episodes,
            imagery=args.imagery,
            setting=args.setting,
            cache_dir=args.cache_dir,
            device=torch.device(args.device) if args.device else None,
            workers=args.eval_workers,
            video_dir=args.video,
            only=args.checkpoint,
            view_choice=args.view_choice,
            imagery_options=dict(args.imagery_option),
        )
    except (FileNotFoundError, ValueError) as error:  # no checkpoint it can evaluate or write
        print(f"nerf-transporter evaluate-checkpoints: {error}", file=sys.stderr)
        return 2
    best = best_record(records)
    searched = any("view_search" in record for record in records)
    view_header = " | view search: true view / within one step / median rank" if searched else ""
    print(f"| checkpoint | step | {args.split} success (n, 95% CI){view_header} |")
    print("| --- | --- | --- |" + (" --- |" if searched else ""))
    for record in records:
        mark = " (best)" if record is best else ""
        name = Path(record["checkpoint"]).name
        view = f" | {view_search_text(record.get('view_search'))}" if searched else ""
        print(f"| {name}{mark} | {record['global_step']} | {cell(record)}{view} |")
    if best is None:
        print(
            "nerf-transporter evaluate-checkpoints: every evaluation had erred episodes (see the "
            "warnings above); none can be chosen. Fix the cause and evaluate again.",
            file=sys.stderr,
        )
        return 1
    config = args.run_dir / "config.yaml"
    config_arg = str(config) if config.exists() else "<the run's config>"
    print(
        f"\ntest the best one with:\n  lightning test --config {config_arg} --ckpt_path {best['checkpoint']}"
    )
    if args.json:
        summary = [
            {
                key: record[key]
                for key in (
                    "checkpoint",
                    "global_step",
                    "episodes",
                    "successes",
                    "success_rate",
                    "ci_low",
                    "ci_high",
                    "errors",
                )
            }
            for record in records
        ]
        print(json.dumps({"split": args.split, "checkpoints": summary, "best": best["checkpoint"]}))
    return 0
