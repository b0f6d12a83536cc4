"""mira's view search measured on validation demonstrations, without a simulator: the true
view's rank among all views and the place label's rank in it, logged every N training steps
between closed-loop rounds (`OfflineViewSearch`; the closed-loop figures are
`evaluation.view_search`'s)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from lightning.pytorch.callbacks import Callback

from nerf_transporter import geometry as g
from nerf_transporter.data.generate import generate_dataset
from nerf_transporter.data.labels import labels_from_view_action
from nerf_transporter.data.preprocess import network_input
from nerf_transporter.methods.mira import view_rank, view_scores


def offline_view_search(
    method: Any, demos: list[Any], views: np.ndarray, pixel_size: float, n_rotations: int
) -> dict[str, float]:
    """The view search on demonstrations, without a simulator: for each demo's own pick label,
    the true view's rank among all views by the search's score (`true_view_rank_median`,
    `view_top1`) and the rank of the place label's logit among all placements of the true view
    (`label_rank_median`, 0 = the argmax). Medians over the demos."""
    true_ranks, label_ranks = [], []
    for demo in demos:
        labels = labels_from_view_action(demo.view_action, pixel_size, n_rotations)
        images = network_input(demo.colour, demo.height)
        scores = []
        for start, logits in method.place_logits(images, demo.height, views, labels.pick_pixel):
            scores.append(view_scores(logits, method.view_choice).cpu())
            inside = labels.place_view - start
            if 0 <= inside < len(logits):
                true_logits = logits[inside]
                label = true_logits[labels.rotation_bin][labels.place_pixel]
                label_ranks.append(int((true_logits > label).sum()))
        true_ranks.append(view_rank(torch.cat(scores).double().numpy(), labels.place_view))
    return {
        "true_view_rank_median": float(np.median(true_ranks)),
        "view_top1": float(np.mean(np.array(true_ranks) == 0)),
        "label_rank_median": float(np.median(label_ranks)),
    }


class OfflineViewSearch(Callback):
    """Logs `offline/true_view_rank_median`, `offline/view_top1` and `offline/label_rank_median`
    (`offline_view_search`) on the first `demos` validation demonstrations every `every_n_steps`
    training steps: learning followed between closed-loop rounds, no simulator needed. Only for
    methods that search views (`mira`); the demonstrations are generated where missing, as
    `lightning fit` generates its training data. Evaluation leaves the training run unchanged
    (`torch.random.fork_rng`, no gradients, the training mode restored)."""

    def __init__(self, every_n_steps: int = 250, demos: int = 10) -> None:
        if every_n_steps < 1:
            raise ValueError(f"every_n_steps must be >= 1, got {every_n_steps}")
        if demos < 1:
            raise ValueError(f"demos must be >= 1, got {demos}")
        self.every_n_steps, self.demos = every_n_steps, demos
        self._demos: list[Any] | None = None

    def on_fit_start(self, trainer: Any, pl_module: Any) -> None:
        if not hasattr(pl_module, "place_logits") or not trainer.is_global_zero:
            return
        datamodule = trainer.datamodule
        if datamodule.generate_missing:
            config = datamodule.generation_config("validation")
            generate_dataset(config, self.demos, datamodule.data_dir)
        self._demos = datamodule.load_split("validation", self.demos, pl_module.input_kind)

    def on_train_batch_end(
        self, trainer: Any, pl_module: Any, outputs: object, batch: object, batch_idx: int
    ) -> None:
        step = trainer.global_step
        if self._demos is None or step % self.every_n_steps != 0:
            return
        was_training = pl_module.training
        pl_module.train(False)
        try:
            with torch.random.fork_rng(), torch.no_grad():
                figures = offline_view_search(
                    pl_module,
                    self._demos,
                    g.view_grid(trainer.datamodule.setting),
                    pl_module.pixel_size,
                    pl_module.n_rotations,
                )
        finally:
            pl_module.train(was_training)
        for logger in trainer.loggers:
            logger.log_metrics({f"offline/{k}": v for k, v in figures.items()}, step=step)
