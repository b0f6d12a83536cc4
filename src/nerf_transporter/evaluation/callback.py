"""`SuccessRateCallback`: closed-loop success on validation seeds during training.

Configured in the YAML under `trainer.callbacks`; every `every_n_steps` optimiser steps and at the end
of fit it runs `episodes` validation episodes (`splits.split_seed("validation", i)`) and logs
`eval/success_rate`, its 95% Wilson interval (`eval/success_rate_low`, `eval/success_rate_high`) and
`eval/episodes`, the rate of the project's stricter 6-DoF check with its interval
(`eval/strict_success_rate`, `eval/strict_success_rate_low`, `eval/strict_success_rate_high`; not
logged where an episode that ran was not judged by it), for `mira` the view search against the
true view (`eval/view_top1`, `eval/view_within_one_step`, `eval/true_view_rank_median`,
`evaluation.view_search`; from this process's episodes under DDP), plus an image strip of the first rollouts
(top-down view before the action with the chosen pick and place drawn in, and after it; captioned
with the seed and the outcome or its reason, framed lime on success, magenta on failure, grey on
error). The first `video_episodes` of each round are recorded as mp4s in the run folder
(`videos/step<N>/`), the first also as an animated GIF in TensorBoard (`eval/rollout_video`). `ModelCheckpoint(monitor="eval/success_rate")` with the
same `every_n_train_steps` keeps the checkpoints with the best validation success (the Transporter
authors' protocol). Under DDP the seeds are shared out among the processes and the counts summed.

Each round's figures and episode records are kept in the run folder as `validation/step<N>.json`
(`round_record`), where `run-cell` reads the view-search figures of its rounds.

The episodes run in `eval_workers` worker processes (default: the cores available to this process,
its share under DDP), each with its own simulator and copy of the model, with the results of a serial
run (`evaluation.workers`).

Episodes that erred (imagery cache I/O, the imagery fit, ...: not the robot's doing) are left out of
the rate and logged as `eval/errors`; a round with any error hands ModelCheckpoint a NaN success rate,
which ranks below every real one, so checkpoint selection ignores that round.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import lightning.pytorch as pl
import numpy as np
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_info
from tensorboard.compat.proto.summary_pb2 import Summary
from torch.utils.tensorboard.summary import hparams as hparams_summary
from torchmetrics.aggregation import SumMetric

from nerf_transporter.atomic import write_json
from nerf_transporter.drawing import captioned
from nerf_transporter.evaluation.metrics import SuccessRate, cell, wilson_interval
from nerf_transporter.evaluation.rollout import (
    DEFAULT_CACHE_DIR,
    EpisodeResult,
    EvaluationSpec,
    Evaluator,
)
from nerf_transporter.evaluation.video import draw_action, gif_bytes
from nerf_transporter.evaluation.view_search import VIEW_SEARCH_FIGURES, view_search_text
from nerf_transporter.evaluation.view_search import summary as view_search_summary
from nerf_transporter.parallel import share_cores
from nerf_transporter.splits import split_seed

# settings shown in TensorBoard's HParams tab, where the method / DataModule has them
MODEL_HPARAMS = ("lr", "width", "pixel_size", "n_rotations", "crop_size")
DATA_HPARAMS = ("n_demos", "batch_size", "n_negative_views", "augment", "colour_augment")
# frame colours chosen apart from every object colour of the tasks (sim/assets.py COLORS)
OUTCOME_COLOURS = {
    "success": np.array([128, 255, 0], dtype=np.uint8),  # lime
    "failure": np.array([255, 0, 255], dtype=np.uint8),  # magenta
    "error": np.array([110, 110, 110], dtype=np.uint8),  # grey
}


def round_record_path(log_dir: str | Path, step: int) -> Path:
    """Where a validation round's figures and episode records are kept: the run's
    `validation/step<N>.json`."""
    return Path(log_dir, "validation", f"step{step:06d}.json")


def round_record(log_dir: str | Path, step: int) -> dict | None:
    """The validation round of `step` kept in a run folder, or None (a fit without closed-loop
    validation, or one before the rounds were kept)."""
    path = round_record_path(log_dir, step)
    return json.loads(path.read_text()) if path.is_file() else None


def round_view_search(log_dir: str | Path, step: int) -> dict[str, float]:
    """The view-search figures (`view_search.VIEW_SEARCH_FIGURES`) of the validation round of
    `step` kept in a run folder; empty where it holds none."""
    figures = (round_record(log_dir, step) or {}).get("figures", {})
    return {
        name: figures[f"eval/{name}"] for name in VIEW_SEARCH_FIGURES if f"eval/{name}" in figures
    }


def rollout_column(result: EpisodeResult, border: int = 4) -> np.ndarray:
    """One recorded episode: caption (seed, outcome or why not), the top-down view before the
    action with its pick (ring) and place (cross) drawn in, the view after; framed by outcome."""
    before, after = (np.array(frame) for frame in result.frames)
    if result.action is not None:
        draw_action(before, result.action["pick"][:3], result.action["place"][:3])
    column = captioned(
        np.concatenate([before, after], axis=0), [f"seed {result.seed}", result.outcome_text()]
    )
    framed = np.empty(
        (column.shape[0] + 2 * border, column.shape[1] + 2 * border, 3), dtype=np.uint8
    )
    framed[:] = OUTCOME_COLOURS[result.outcome]
    framed[border:-border, border:-border] = column
    return framed


def rollout_strip(results: list[EpisodeResult]) -> np.ndarray | None:
    """The recorded episodes side by side (`rollout_column`), bottom-aligned; HWC uint8."""
    columns = [rollout_column(result) for result in results if result.frames is not None]
    if not columns:
        return None
    height = max(column.shape[0] for column in columns)
    padded = [np.pad(column, ((height - column.shape[0], 0), (0, 0), (0, 0))) for column in columns]
    return np.concatenate(padded, axis=1)


class SuccessRateCallback(Callback):
    """Evaluate closed-loop success on validation seeds every `every_n_steps` and at the end of fit.

    Task, setting, imagery kind and imagery config default to those of the DataModule (the
    evaluation imagery must be built like the training imagery); `imagery: oracle` swaps in the
    simulator's ground-truth views. `strip_episodes` rollouts are drawn into the logged image strip.
    Imagery is cached under `cache_dir` per seed, so only the first evaluation fits NeRFs.
    `eval_workers` processes run the episodes (None: one per available core, 1: in this process).
    """

    def __init__(
        self,
        every_n_steps: int = 1000,
        episodes: int = 10,
        imagery: str | None = None,
        setting: str | None = None,
        cache_dir: str | None = DEFAULT_CACHE_DIR,
        strip_episodes: int = 4,
        eval_workers: int | None = None,
        video_episodes: int = 1,
    ) -> None:
        if every_n_steps < 1:
            raise ValueError(f"every_n_steps must be >= 1, got {every_n_steps}")
        if episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {episodes}")
        if eval_workers is not None and eval_workers < 1:
            raise ValueError(f"eval_workers must be >= 1, got {eval_workers}")
        self.every_n_steps = every_n_steps
        self.episodes = episodes
        self.imagery = imagery
        self.setting = setting
        self.cache_dir = cache_dir
        self.strip_episodes = strip_episodes
        self.eval_workers = eval_workers
        self.video_episodes = video_episodes
        self.metric = SuccessRate()
        self.error_count = SumMetric()  # erred episodes, summed over DDP processes
        self.strict_metric = SuccessRate()  # the strict 6-DoF check, over the episodes judged by it
        self.unjudged_count = SumMetric()  # episodes that ran without a strict check (None)
        self._evaluator: Evaluator | None = None
        self._last_step: int | None = None

    # -- evaluation ---------------------------------------------------------------------------

    def _get_evaluator(self, trainer: pl.Trainer) -> Evaluator:
        if self._evaluator is None:
            spec = EvaluationSpec.from_datamodule(
                trainer.datamodule,
                setting=self.setting,
                imagery=self.imagery,
                cache_dir=self.cache_dir,
            )
            self._evaluator = Evaluator(spec)
        return self._evaluator

    def evaluate(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> dict[str, float]:
        """Run this process's share of the validation episodes; return the pooled figures."""
        indices = range(trainer.global_rank, self.episodes, trainer.world_size)
        seeds = [split_seed("validation", index) for index in indices]
        workers, threads = share_cores(len(seeds), self.eval_workers, trainer.num_devices)
        log_dir = trainer.log_dir  # a collective call under DDP: every process asks
        recording = trainer.is_global_zero and log_dir is not None and self.video_episodes > 0
        results = self._get_evaluator(trainer).run(
            pl_module,
            seeds,
            progress=trainer.is_global_zero,
            desc=f"validation episodes at step {trainer.global_step}",
            record_frames=self.strip_episodes,
            workers=workers,
            threads=threads,
            video_dir=Path(log_dir, "videos", f"step{trainer.global_step:06d}")
            if recording
            else None,
            video_episodes=self.video_episodes,
        )
        self.metric = self.metric.to(pl_module.device)
        self.metric.reset()
        self.metric.update([result.success for result in results if result.error is None])
        self.error_count = self.error_count.to(pl_module.device)
        self.error_count.reset()
        self.error_count.update(float(sum(result.error is not None for result in results)))
        rate = float(self.metric.compute())
        successes, episodes = self.metric.counts()
        errors = int(self.error_count.compute())
        low, high = wilson_interval(successes, episodes)
        figures = {
            "eval/success_rate": rate,
            "eval/success_rate_low": low,
            "eval/success_rate_high": high,
            "eval/episodes": float(episodes),
            "eval/errors": float(errors),
        }
        misses = [f"{r.seed}: {r.failure_text()}" for r in results if not r.success]
        counts = {"successes": successes, "episodes": episodes, "errors": errors}
        summary = cell(counts | {"ci_low": low, "ci_high": high})
        strict = self._strict_counts(pl_module, results)
        if strict is not None:
            strict_low, strict_high = wilson_interval(*strict)
            figures |= {
                "eval/strict_success_rate": strict[0] / strict[1],
                "eval/strict_success_rate_low": strict_low,
                "eval/strict_success_rate_high": strict_high,
            }
            strict_cell = cell(
                {"successes": strict[0], "episodes": strict[1]}
                | {"ci_low": strict_low, "ci_high": strict_high}
            )
            summary += f", strict 6-DoF {strict_cell}"
        view = view_search_summary([result.view_search for result in results])
        if view is not None:  # mira: where the view search placed against the true view
            figures |= {f"eval/{name}": value for name, value in view.items()}
            summary += f"; view search: {view_search_text(view)}"
        rank_zero_info(
            f"step {trainer.global_step}: validation success (n, 95% CI) {summary}"
            + (
                "; erred episodes are not counted and this round is not used to select checkpoints"
                if errors
                else ""
            )
            + "".join(f"\n  seed {line}" for line in misses)
        )
        if trainer.is_global_zero and log_dir is not None:
            write_json(
                round_record_path(log_dir, trainer.global_step),
                {
                    "step": trainer.global_step,
                    "figures": figures,
                    "episode_results": [result.to_json() for result in results],
                },
            )
        video = next((result.video for result in results if result.video is not None), None)
        self._log(trainer, figures, rollout_strip(results), video)
        self._last_step = trainer.global_step
        return figures

    def _strict_counts(
        self, pl_module: pl.LightningModule, results: list[EpisodeResult]
    ) -> tuple[int, int] | None:
        """(strict 6-DoF successes, episodes) of the episodes that ran, pooled over processes;
        None where one that ran has no strict check (a missing check is no failure) or none ran."""
        ran = [result for result in results if result.error is None]
        judged = [result.strict_success for result in ran if result.strict_success is not None]
        self.strict_metric = self.strict_metric.to(pl_module.device)
        self.strict_metric.reset()
        self.strict_metric.update(judged)
        self.unjudged_count = self.unjudged_count.to(pl_module.device)
        self.unjudged_count.reset()
        self.unjudged_count.update(float(len(ran) - len(judged)))
        successes, episodes = self.strict_metric.counts()  # collective calls: every process asks
        unjudged = int(self.unjudged_count.compute())
        return None if unjudged or not episodes else (successes, episodes)

    def _log(
        self,
        trainer: pl.Trainer,
        figures: dict[str, float],
        strip: np.ndarray | None,
        video: str | None,
    ) -> None:
        for logger in trainer.loggers:
            logger.log_metrics(figures, step=trainer.global_step)
            if not isinstance(logger, TensorBoardLogger) or not trainer.is_global_zero:
                continue
            if strip is not None:
                logger.experiment.add_image(
                    "eval/rollouts", strip, trainer.global_step, dataformats="HWC"
                )
            if video is not None:
                gif, (height, width) = gif_bytes(video)
                image = Summary.Image(
                    height=height, width=width, colorspace=3, encoded_image_string=gif
                )
                summary = Summary(value=[Summary.Value(tag="eval/rollout_video", image=image)])
                logger.experiment._get_file_writer().add_summary(summary, trainer.global_step)

    def hyperparameters(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> dict:
        """What the HParams tab compares runs by: method, task, setting, budget, key settings."""
        spec = self._get_evaluator(trainer).spec
        params = {
            "method": str(getattr(pl_module, "name", type(pl_module).__name__)),
            "task": spec.task,
            "setting": spec.setting,
            "imagery": spec.imagery
            if getattr(pl_module, "input_kind", None) == "imagery"
            else None,
            "max_steps": trainer.max_steps,
            "validation_episodes": self.episodes,
        }
        params |= {key: pl_module.hparams.get(key) for key in MODEL_HPARAMS}
        params |= {key: getattr(trainer.datamodule, key, None) for key in DATA_HPARAMS}
        return {key: value for key, value in params.items() if value is not None}

    # -- hooks --------------------------------------------------------------------------------

    def on_fit_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        """Declare `eval/success_rate` as the HParams metric of this run, beside its settings (the
        HParams tab then reads the metric from the evaluations' scalars)."""
        loggers = [lg for lg in trainer.loggers if isinstance(lg, TensorBoardLogger)]
        if not loggers or not trainer.is_global_zero:
            return
        params = self.hyperparameters(trainer, pl_module)
        summaries = hparams_summary(params, {"eval/success_rate": 0.0})  # names only, no value
        for logger in loggers:
            writer = logger.experiment._get_file_writer()  # as TensorBoardLogger.log_hyperparams
            for summary in summaries:
                writer.add_summary(summary)

    def on_train_batch_end(
        self,
        trainer: pl.Trainer,
        pl_module: pl.LightningModule,
        outputs: object,
        batch: object,
        batch_idx: int,
    ) -> None:
        step = trainer.global_step
        last = 0 < trainer.max_steps <= step
        if step == self._last_step or not (step % self.every_n_steps == 0 or last):
            return
        figures = self.evaluate(trainer, pl_module)
        if figures["eval/errors"]:
            figures["eval/success_rate"] = math.nan  # ModelCheckpoint ranks NaN below every rate
        # into trainer.callback_metrics (ModelCheckpoint's monitor, progress bar); loggers got them
        for name, value in figures.items():
            pl_module.log(name, value, logger=False, prog_bar=name == "eval/success_rate")

    def on_train_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if trainer.global_step != self._last_step:
            self.evaluate(trainer, pl_module)

    def teardown(self, trainer: pl.Trainer, pl_module: pl.LightningModule, stage: str) -> None:
        if self._evaluator is not None:
            self._evaluator.close()
            self._evaluator = None
