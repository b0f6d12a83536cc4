"""Closed-loop `trainer.test` (`lightning test --config ... --ckpt_path ...`): `ClosedLoopTestCallback`.

The DataModule's test dataloader yields episode seeds (`data.seeds.seed_loader`; under DDP each
process gets its share). `ClosedLoopTestCallback` collects them as the test loop hands them out
and at the end of the epoch runs them with an `Evaluator` in the DataModule's `test_workers` worker
processes (default: one per core available to this process), pools the outcomes (across DDP
processes), logs `test/success_rate`, its 95% Wilson interval, the episode count, the erred
episodes (`test/errors`, not counted in the rate) and the rate of the stricter 6-DoF check
(`test/strict_success_rate` and its interval; every episode record holds its `strict_success`),
and writes `results-<checkpoint>.json` beside the checkpoint (`results-<checkpoint>-<setting>.json`
when the DataModule's `test_setting` differs from its training `setting`; in the run folder for a
policy shipped in the package). A results file is never replaced: testing the same checkpoint
again writes `...-2.json`, and `nerf-transporter report` takes the newest. `lightning test` exits
non-zero when any episode erred. The CLI adds the callback to every trainer it builds (also when a
config lists its own callbacks); a Trainer built by hand needs it in its `callbacks`.

Why a callback around Lightning's own test loop: judging a policy is evaluation's business, so the
methods (`methods/base.py`) know nothing of it and import nothing from here. Lightning insists on
a `test_step` to run `trainer.test`; `Method.test_step` does nothing, and the callback reads the
seeds from `on_test_batch_end` and plays them all in `on_test_epoch_end`, so that the worker
processes take episodes as they become free. The test loop still does what it does well: it loads
the checkpoint, shares the seeds out under DDP, shows the progress bar and returns the logged
`test/*` figures from `trainer.test`. A custom loop (`trainer.test_loop` replaced) would redo all
of that for no gain.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import os
import sys
import time
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import torch
from lightning.pytorch import LightningModule, Trainer
from lightning.pytorch.callbacks import Callback

from nerf_transporter.atomic import write_new_json
from nerf_transporter.data.episode import file_sha256
from nerf_transporter.device_info import describe_device
from nerf_transporter.evaluation.journal import EpisodeJournal
from nerf_transporter.evaluation.metrics import cell, summarize
from nerf_transporter.evaluation.rollout import DEFAULT_CACHE_DIR, EvaluationSpec, Evaluators
from nerf_transporter.evaluation.view_search import summary as view_search_summary
from nerf_transporter.parallel import share_cores
from nerf_transporter.pretrained import PRETRAINED_DIR
from nerf_transporter.provenance import code_identity, git_state
from nerf_transporter.sim.fingerprint import world_fingerprint

log = logging.getLogger(__name__)

# the strict check's figures logged by `trainer.test` (test/<name>), where the episodes have it
STRICT_LOGGED = ("strict_success_rate", "strict_ci_low", "strict_ci_high")


def results_stem(
    checkpoint: str | None, global_step: int, setting: str, training_setting: str
) -> str:
    """`results-<checkpoint stem>` (`results-step<N>` without a checkpoint file), with
    `-<setting>` appended when testing in another setting than trained in."""
    name = Path(checkpoint).stem if checkpoint else f"step{global_step}"
    stem = f"results-{name}"
    return stem if setting == training_setting else f"{stem}-{setting}"


def results_directory(checkpoint: str | None, log_dir: str | None) -> Path:
    """Beside the checkpoint, except for a policy shipped in the package (`nerf_transporter/
    pretrained` is no place for results) or no checkpoint at all: then the run folder."""
    if checkpoint and Path(checkpoint).resolve().parent != PRETRAINED_DIR:
        return Path(checkpoint).parent
    return Path(log_dir or ".")


def results_record(
    results: list[dict[str, Any]],
    *,
    method: torch.nn.Module,
    spec: EvaluationSpec,
    trained_setting: str,
    split: str,
    checkpoint: str | None,
    global_step: int | None,
    wall_s: float,
) -> dict[str, Any]:
    """The results file's payload: identification, summary figures and every episode's record.

    "setting" is the setting the episodes ran in, "trained_setting" the one the policy was trained
    in (its DataModule's `setting`); "imagery" is how the views were built for an imagery method
    (nerf, oracle), None for the methods that see the RGB-D heightmap or the state;
    "checkpoint_sha256" the content hash of the checkpoint file tested (None without a local
    file), by which `export-pretrained` knows it. A method's test-time options
    (`Method.test_time_options`: mira's view choice) and, for mira, the view search's figures
    (`evaluation.view_search.summary`) follow the success figures; "git" (the commit this ran at)
    and "machine" (`test`: the machine and device that ran the policy) say where they come from.
    """
    results = sorted(results, key=lambda result: result["seed"])
    view_search = view_search_summary([result.get("view_search") for result in results])
    options = policy_test_time_options(method)
    return {
        "method": method_name(method),
        "task": spec.task,
        "setting": spec.setting,
        "trained_setting": trained_setting,
        "split": split,
        "imagery": spec.imagery if getattr(method, "input_kind", None) == "imagery" else None,
        "checkpoint": checkpoint,
        "checkpoint_sha256": file_sha256(checkpoint)
        if checkpoint and Path(checkpoint).is_file()
        else None,
        "global_step": global_step,
        "world": world_fingerprint(),
        **summarize(results),
        **({"test_time_options": options} if options else {}),
        **({"view_search": view_search} if view_search else {}),
        "wall_s": wall_s,
        "git": git_state(),
        "machine": {"test": describe_device(_device_of(method))},
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "episode_results": results,
    }


def policy_test_time_options(method: Any) -> dict[str, Any]:
    """A policy's test-time options and their values (`Method.test_time_options`; {} for none)."""
    return {key: getattr(method, key) for key in getattr(method, "test_time_options", ())}


def _device_of(method: Any) -> torch.device:
    """Where a policy's weights live (the CPU for a policy without any)."""
    parameters = method.parameters() if isinstance(method, torch.nn.Module) else ()
    return next((parameter.device for parameter in parameters), torch.device("cpu"))


def evaluate_policy(
    method: torch.nn.Module,
    datamodule: Any,
    seeds: list[int],
    *,
    split: str,
    setting: str | None = None,
    imagery: str | None = None,
    imagery_options: dict[str, Any] | None = None,
    cache_dir: str | None = DEFAULT_CACHE_DIR,
    workers: int | None = None,
    processes: int = 1,
    checkpoint: str | None = None,
    global_step: int | None = None,
    progress: bool = True,
    desc: str = "episodes",
    video_dir: str | os.PathLike | None = None,
    evaluators: Evaluators | None = None,
    gather: Callable[[list[dict[str, Any]]], list[dict[str, Any]]] | None = None,
    journal_dir: str | os.PathLike | None = None,
    keep: Callable[[dict[str, Any]], object] | None = None,
) -> dict[str, Any]:
    """The results record (`results_record`) of a policy on `seeds` of `split`: in the scene of its
    DataModule (`EvaluationSpec.from_datamodule`, with `setting`, `imagery`, `imagery_options`
    and `cache_dir`; the record names the `imagery_options` where given), in
    `workers` processes on this process's share of the cores (`share_cores`, with `processes`
    processes evaluating side by side, as DDP ranks do), every episode recorded into `video_dir`
    where given. `evaluators` keeps the Evaluator open for the caller's next policy (default: one
    of its own, closed after); `gather` pools the episodes of all DDP processes. `checkpoint` and
    `global_step` name the policy in the record.

    With `journal_dir`, each finished episode is journalled there (`evaluation.journal`) and the
    episodes an interrupted evaluation of the same identity journalled are taken instead of run
    again (the record counts them in "resumed_episodes"; its "wall_s" is this call's); `keep`, called
    with the record, writes it before the journal is removed."""
    start = time.perf_counter()
    spec = EvaluationSpec.from_datamodule(
        datamodule,
        split=split,
        setting=setting,
        imagery=imagery,
        imagery_options=imagery_options,
        cache_dir=cache_dir,
    )
    journal = None
    if journal_dir is not None:
        journal = EpisodeJournal(journal_dir, journal_identity(method, spec, split, checkpoint))
    resumed = journal.finished(seeds) if journal is not None else {}
    if resumed:
        log.info(
            "%s: %d of %d episodes resumed from %s", desc, len(resumed), len(seeds), journal.path
        )
    to_run = [seed for seed in seeds if seed not in resumed]
    workers, threads = share_cores(len(to_run), workers, processes)
    with contextlib.nullcontext(evaluators) if evaluators is not None else Evaluators() as kept:
        episodes = kept.get(spec).run(
            method,
            to_run,
            progress=progress,
            desc=desc,
            workers=workers,
            threads=threads,
            video_dir=video_dir,
            on_result=journal.record if journal is not None else None,
        )
    results = [episode.to_json() for episode in [*resumed.values(), *episodes]]
    record = results_record(
        gather(results) if gather else results,
        method=method,
        spec=spec,
        trained_setting=datamodule.setting,
        split=split,
        checkpoint=checkpoint,
        global_step=global_step,
        wall_s=time.perf_counter() - start,
    )
    record |= {"imagery_options": dict(imagery_options)} if imagery_options else {}
    record |= {"resumed_episodes": len(resumed)} if resumed else {}
    if keep is not None:
        keep(record)
    if journal is not None:
        journal.remove()
    return record


def journal_identity(
    method: torch.nn.Module, spec: EvaluationSpec, split: str, checkpoint: str | None
) -> dict[str, Any]:
    """What an evaluation's episodes depend on besides their seeds (`evaluation.journal`): the
    checkpoint's bytes, the split, the scene with its imagery key (world fingerprint included), the
    policy's test-time options and the code."""
    options = policy_test_time_options(method)
    return {
        "checkpoint_sha256": file_sha256(checkpoint) if checkpoint else None,
        "split": split,
        "scene": {"task": spec.task, "setting": spec.setting, "imagery": spec.imagery},
        "imagery_key": spec.imagery_key(),
        "test_time_options": options,
        "code": code_identity(),
    }


def checkpoint_step(path: str | os.PathLike) -> int:
    """The global step a checkpoint was saved at."""
    checkpoint = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    return int(checkpoint["global_step"])


def method_name(module: torch.nn.Module) -> str:
    """The name of a method (`mira`, `transporter_se2`, ...: the class attribute `name`)."""
    return str(getattr(module, "name", type(module).__name__))


def strict_cell(record: dict[str, Any]) -> str:
    """The strict 6-DoF success of a results record as `cell` writes a rate, with its count."""
    figures = {
        "episodes": record["episodes"],
        "successes": record["strict_successes"],
        "ci_low": record["strict_ci_low"],
        "ci_high": record["strict_ci_high"],
    }
    return f"{cell(figures)} - {record['strict_successes']} of {record['episodes']}"


def erred_episodes_text(record: dict[str, Any]) -> str:
    """One line per erred episode of a results record, under a headline."""
    erred = [result for result in record["episode_results"] if result.get("error") is not None]
    lines = [f"  seed {result['seed']}: {result['error']}" for result in erred]
    return (
        f"{len(erred)} of {len(record['episode_results'])} episodes erred (not the robot's doing; "
        "left out of the success rate):\n" + "\n".join(lines)
    )


def erred_seeds_line(record: dict[str, Any]) -> str:
    """The erred episodes of a results record in one line, with what to do."""
    seeds = ", ".join(str(seed) for seed in record["erred_seeds"])
    return (
        f"{record['errors']} episodes erred (seeds {seeds}) and are left out of the success rate; "
        "fix the cause (see the messages above) and test again"
    )


class ClosedLoopTestCallback(Callback):
    """`trainer.test` plays the test seeds closed loop and writes the results file.

    With `video_dir` set (`lightning test ... --video DIR`), every episode is also recorded there
    as an mp4. After a test, `record` holds the results payload (for the CLI's exit status)."""

    plays_test_seeds = True  # what `Method.on_test_start` looks for among the trainer's callbacks

    def __init__(self, video_dir: str | None = None) -> None:
        self.video_dir = video_dir
        self.record: dict[str, Any] | None = None
        self._seeds: list[int] = []

    def on_test_epoch_start(self, trainer: Trainer, pl_module: LightningModule) -> None:
        self.record = None
        self._seeds = []

    def on_test_batch_end(
        self,
        trainer: Trainer,
        pl_module: LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int = 0,
    ) -> None:
        """Collect this process's seeds; they run together at the end of the epoch, so that the
        worker processes share them out as they become free."""
        self._seeds.extend(int(seed) for seed in torch.as_tensor(batch).flatten().tolist())

    def on_test_epoch_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        datamodule = trainer.datamodule
        checkpoint = trainer.ckpt_path
        if not checkpoint:
            step = trainer.global_step
        elif Path(checkpoint).is_file():
            step = checkpoint_step(checkpoint)
        else:
            step = None  # a checkpoint behind a URL: Lightning read it, its step is not at hand
        record = evaluate_policy(
            pl_module,
            datamodule,
            self._seeds,
            split="test",
            workers=getattr(datamodule, "test_workers", None),
            processes=trainer.num_devices,
            checkpoint=str(checkpoint) if checkpoint else None,
            global_step=step,
            progress=trainer.is_global_zero,
            desc="test episodes",
            video_dir=self.video_dir,
            gather=functools.partial(gather_json, pl_module) if trainer.world_size > 1 else None,
        )
        for name in ("success_rate", "ci_low", "ci_high", "episodes", "errors", *STRICT_LOGGED):
            if record[name] is not None:  # rounded for Lightning's table; the file keeps all digits
                pl_module.log(f"test/{name}", round(float(record[name]), 4))
        self.record = record
        log_dir = trainer.log_dir  # a collective call under DDP: every process asks for it
        directory = results_directory(str(checkpoint) if checkpoint else None, log_dir)
        if trainer.is_global_zero:
            stem = results_stem(
                record["checkpoint"], record["global_step"], record["setting"], datamodule.setting
            )
            path = write_new_json(directory, stem, record)
            print(f"test success: {cell(record)} - {record['successes']} of {record['episodes']}")
            if record["strict_successes"] is not None:
                print(f"strict 6-DoF success: {strict_cell(record)}")
            print(f"closed-loop test results written to {path}")
            if record["errors"]:
                print(erred_episodes_text(record), file=sys.stderr)


def gather_json(module: Any, records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Concatenate every process's JSON records (sent as padded byte tensors: no pickle)."""
    payload = torch.tensor(list(json.dumps(records).encode()), dtype=torch.uint8)
    sizes = module.all_gather(torch.tensor(len(payload), device=module.device)).flatten()
    padded = torch.zeros(int(sizes.max()), dtype=torch.uint8)
    padded[: len(payload)] = payload
    parts = module.all_gather(padded.to(module.device)).cpu()
    return [
        record
        for part, size in zip(parts, sizes.tolist(), strict=True)
        for record in json.loads(bytes(part[:size].tolist()).decode())
    ]
