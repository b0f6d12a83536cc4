"""`mira`: Transporter networks searching the NeRF mental imagery (docs/conventions.md,
"Labels and actions")."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from nerf_transporter import geometry as g
from nerf_transporter.data.labels import action_from_labels
from nerf_transporter.data.preprocess import network_input
from nerf_transporter.methods.base import (
    Action,
    AttentionTransportMethod,
    Batch,
    check_image_shape,
    overlay,
    softmax_map,
)
from nerf_transporter.models.transport import correlate_spectrum, kernel_spectrum


def over_workspace(points: np.ndarray) -> np.ndarray:
    """Whether world points (..., 3) lie within the workspace bounds in x and y (z free)."""
    points = np.asarray(points, dtype=float)
    (x_low, x_high), (y_low, y_high) = g.BOUNDS[0], g.BOUNDS[1]
    x, y = points[..., 0], points[..., 1]
    return (x_low <= x) & (x <= x_high) & (y_low <= y) & (y <= y_high)


def pixels_over_workspace(
    height: np.ndarray, view_rotation: np.ndarray, pixel_size: float = g.PIXEL_SIZE
) -> np.ndarray:
    """(H, W) mask of a view's pixels whose surface point (at the view's height image) lies over the
    workspace. A tilted view's edge pixels see the table beyond it (a view rolled by a sees the
    table point y = y' / cos(a) at its pixel y').

    A choice of the policy, not a convention of the world, so it lives here and not in `geometry`
    (whose source is part of the world fingerprint, `sim/fingerprint.py`).
    """
    pixels = np.stack(np.indices(np.shape(height)), axis=-1)
    return over_workspace(
        g.view_to_world(g.pixel_to_world(pixels, height, pixel_size), view_rotation)
    )


# How `act` ranks the views (docs/conventions.md, "Labels and actions"):
# - "max_logit": the view holding the highest raw transport logit over all views;
# - "view_softmax": each view's logits through a softmax of their own, the view whose highest
#   probability is largest (MIRA's rule).
VIEW_CHOICES = ("max_logit", "view_softmax")


@dataclass(frozen=True)
class PlaceSearch:
    """One transport search of the imagery views for a pick: each view's score under the view-choice
    rule (higher is better) and its best placement (rotation bin, row, col)."""

    pick: tuple[int, int]  # (row, col) in the top-down view
    view_scores: np.ndarray  # [V]
    view_best: np.ndarray  # [V, 3] int: rotation bin, row, col

    @property
    def chosen_view(self) -> int:
        """The view `act` places in: the highest score, the first among equals."""
        return int(np.argmax(self.view_scores))

    def view_rank(self, view: int) -> int:
        """Rank of `view` by score, 0 for the chosen one (`view_rank`)."""
        return view_rank(self.view_scores, view)


def view_rank(scores: np.ndarray, view: int) -> int:
    """Rank of `view` among views scored `scores` [V], 0 for the highest (equal scores rank in
    index order, as `PlaceSearch.chosen_view` breaks ties)."""
    score = scores[view]
    return int((scores > score).sum() + (scores[:view] == score).sum())


def view_scores(logits: torch.Tensor, view_choice: str) -> torch.Tensor:
    """Score of each view from its transport logits [V, R, H, W] (unreachable pixels -inf)."""
    best = logits.flatten(1).amax(1)
    if view_choice == "max_logit":
        return best
    # the log of the view's highest own-softmax probability; a view with no reachable pixel: -inf
    own = best - logits.flatten(1).logsumexp(1)
    return torch.where(torch.isfinite(best), own, best)


class Mira(AttentionTransportMethod):
    """Pick on the top-down imagery view; place by one transport search over all views.

    Training: the place label lies in view 0 of `place_images` (the positive view); the other K views
    are negatives of the same scene, and one softmax runs over views x rotations x pixels.
    `act` searches every view (`place_search`) and places at the best placement of the view that
    `view_choice` ranks first (`VIEW_CHOICES`); the rule is a test-time option: a checkpoint is
    tested under the one its config (or `evaluate-checkpoints --view-choice`) names.
    `view_chunk` views are correlated at a time (bounds memory over a 49- or 121-view grid).
    `act` places only at pixels over the workspace (`pixels_over_workspace`): a steep view's edge
    pixels see the table beyond it, where no target lies and the robot does not reach.
    """

    name = "mira"
    input_kind = "imagery"
    test_time_options: ClassVar[tuple[str, ...]] = ("view_choice", "view_chunk")

    def __init__(self, view_chunk: int = 8, view_choice: str = "max_logit", **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if view_chunk < 1:
            raise ValueError(f"view_chunk must be >= 1, got {view_chunk}")
        if view_choice not in VIEW_CHOICES:
            raise ValueError(
                f"view_choice must be one of {', '.join(VIEW_CHOICES)}, got {view_choice!r}"
            )
        self.view_chunk = view_chunk
        self.view_choice = view_choice

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        return self.pick_place_losses(batch["pick_image"], batch["place_images"], batch)

    def heatmaps(self, batch: Batch) -> dict[str, torch.Tensor]:
        """Pick heatmap; place heatmaps (max over rotations, one softmax over all the sample's
        views as in training) of the true view ("place") and of the view the model would choose."""
        pick_image, views = batch["pick_image"][:1], batch["place_images"][:1]
        place = softmax_map(self.transport(pick_image, batch["pick_pixel"][:1], views)[0]).amax(1)
        chosen = int(place.flatten(1).amax(1).argmax())
        label = batch["place_pixel"][0]
        return {
            "pick": self.pick_heatmap(pick_image, batch),
            "place": overlay(views[0, 0], place[0], label, "true view"),
            "place_chosen_view": overlay(
                views[0, chosen],
                place[chosen],
                label if chosen == 0 else None,
                "chosen: the true view" if chosen == 0 else f"chosen: negative view {chosen}",
            ),
        }

    @torch.no_grad()
    def place_logits(
        self, images: torch.Tensor, height: np.ndarray, views: np.ndarray, pick: tuple[int, int]
    ) -> Iterator[tuple[int, torch.Tensor]]:
        """(first view, logits [chunk, R, H, W]) of the transport over the views, `view_chunk` at a
        time, for the pick pixel of the top-down view; pixels not over the workspace are -inf.

        images: network inputs [V, 6, H, W]; height [V, H, W]; views [V, 2] (roll, pitch).
        """
        top = g.top_down_view_index(views)
        pick_image = images[top : top + 1].to(self.device)
        kernels = self.transport.kernels(pick_image, torch.tensor([pick], device=self.device))
        kernel_f = kernel_spectrum(kernels, height.shape[1:])
        rotations = g.view_rotations(views)
        for start in range(0, len(views), self.view_chunk):
            stop = min(start + self.view_chunk, len(views))
            reachable = torch.from_numpy(
                np.stack(
                    [
                        pixels_over_workspace(height[v], rotations[v], self.pixel_size)
                        for v in range(start, stop)
                    ]
                )
            ).to(self.device)
            query = self.transport.query_features(images[None, start:stop].to(self.device))
            logits = correlate_spectrum(query, kernel_f, self.crop_size)[0]
            yield start, logits.masked_fill(~reachable[:, None], -float("inf"))

    def place_search(
        self, images: torch.Tensor, height: np.ndarray, views: np.ndarray, pick: tuple[int, int]
    ) -> PlaceSearch:
        """Every view's score under `view_choice` and its best placement (`place_logits`)."""
        scores, best = [], []
        for _, logits in self.place_logits(images, height, views, pick):
            scores.append(view_scores(logits, self.view_choice).cpu())
            flat = logits.flatten(1).argmax(1).cpu().numpy()
            best.append(np.stack(np.unravel_index(flat, logits.shape[1:]), axis=1))
        return PlaceSearch(
            pick=pick,
            view_scores=torch.cat(scores).double().numpy(),
            view_best=np.concatenate(best).astype(int),
        )

    @torch.no_grad()
    def act(self, observation: dict[str, Any]) -> Action:
        return self.act_with_search(observation)[0]

    @torch.no_grad()
    def act_with_search(self, observation: dict[str, Any]) -> tuple[Action, PlaceSearch]:
        """`act`, with the search it chose from (recorded by evaluation: `evaluation.view_search`)."""
        if "imagery" not in observation:
            raise ValueError(f"observation has no 'imagery' entry (keys: {sorted(observation)})")
        imagery = observation["imagery"]
        height = np.asarray(imagery["height"], dtype=np.float32)
        views = np.asarray(imagery["views"], dtype=float)
        if height.ndim != 3 or views.shape != (height.shape[0], 2):
            raise ValueError(
                f"imagery needs height [V, H, W] and views [V, 2], got {height.shape} and {views.shape}"
            )
        check_image_shape(height.shape[1:], self.pixel_size, "imagery")
        images = network_input(imagery["colour"], height)
        top = g.top_down_view_index(views)
        pick = self.predict_pick(images[top : top + 1].to(self.device))
        search = self.place_search(images, height, views, pick)
        view = search.chosen_view
        rotation, row, col = (int(v) for v in search.view_best[view])
        action = action_from_labels(
            pick,
            float(height[top][pick]),
            (row, col),
            float(height[view, row, col]),
            rotation,
            place_view=(float(views[view, 0]), float(views[view, 1])),
            pixel_size=self.pixel_size,
            n_rotations=self.n_rotations,
        )
        return action, search
