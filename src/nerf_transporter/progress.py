"""Training progress as plain lines, for logs: where stderr is not a terminal, Lightning's bar
would write a carriage-return frame per step into the file; the CLI then uses this instead."""

from __future__ import annotations

import sys
import time
from typing import Any

import lightning.pytorch as pl
from lightning.pytorch.callbacks import Callback


class LineProgress(Callback):
    """One line on stderr at most every `every_s` seconds of training and at its last step: the
    step, the logged progress-bar metrics (losses, the last validation success) and the speed."""

    def __init__(self, every_s: float = 30.0) -> None:
        self.every_s = every_s
        self._last_time = 0.0
        self._last_step = 0

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._last_time, self._last_step = time.perf_counter(), trainer.global_step

    def on_train_batch_end(self, trainer: pl.Trainer, *args: Any) -> None:
        now, step = time.perf_counter(), trainer.global_step
        if now - self._last_time < self.every_s and step != trainer.max_steps:
            return
        if trainer.is_global_zero:
            print(
                self.line(trainer, (step - self._last_step) / (now - self._last_time)),
                file=sys.stderr,
                flush=True,
            )
        self._last_time, self._last_step = now, step

    @staticmethod
    def line(trainer: pl.Trainer, steps_per_s: float) -> str:
        total = f"/{trainer.max_steps}" if trainer.max_steps > 0 else ""
        metrics = "  ".join(
            f"{name} {float(value):.4g}"
            for name, value in sorted(trainer.progress_bar_metrics.items())
        )
        return f"step {trainer.global_step}{total}  {metrics}  {steps_per_s:.2f} steps/s".strip()
