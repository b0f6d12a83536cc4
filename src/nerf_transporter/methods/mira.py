"""`mira`: Transporter networks searching the NeRF mental imagery (docs/conventions.md,
"Labels and actions")."""

from __future__ import annotations

from typing import Any

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


class Mira(AttentionTransportMethod):
    """Pick on the top-down imagery view; place by one transport search over all views.

    Training: the place label lies in view 0 of `place_images` (the positive view); the other K views
    are negatives of the same scene, and one softmax runs over views x rotations x pixels.
    `view_chunk` views are correlated at a time in `act` (bounds memory over a 49- or 121-view grid).
    `act` places only at pixels over the workspace (`pixels_over_workspace`): a steep view's edge
    pixels see the table beyond it, where no target lies and the robot does not reach.
    """

    name = "mira"
    input_kind = "imagery"

    def __init__(self, view_chunk: int = 8, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if view_chunk < 1:
            raise ValueError(f"view_chunk must be >= 1, got {view_chunk}")
        self.view_chunk = view_chunk

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
    def act(self, observation: dict[str, Any]) -> Action:
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
        pick_image = images[top : top + 1].to(self.device)
        pick = self.predict_pick(pick_image)
        kernels = self.transport.kernels(pick_image, torch.tensor([pick], device=self.device))
        kernel_f = kernel_spectrum(kernels, height.shape[1:])
        reachable_pixels = torch.from_numpy(
            np.stack(
                [
                    pixels_over_workspace(view_height, rotation, self.pixel_size)
                    for view_height, rotation in zip(height, g.view_rotations(views), strict=True)
                ]
            )
        ).to(self.device)
        best_value, best = -float("inf"), (0, 0, 0, 0)
        for start in range(0, len(views), self.view_chunk):
            chunk = images[None, start : start + self.view_chunk].to(self.device)
            query = self.transport.query_features(chunk)
            logits = correlate_spectrum(query, kernel_f, self.crop_size)[0]
            reachable = reachable_pixels[start : start + self.view_chunk, None]
            logits = logits.masked_fill(~reachable, -float("inf"))
            value = float(logits.max())
            if value > best_value:
                view, rotation, row, col = np.unravel_index(int(logits.argmax()), logits.shape)
                best_value, best = value, (start + int(view), int(rotation), int(row), int(col))
        view, rotation, row, col = best
        return action_from_labels(
            pick,
            float(height[top][pick]),
            (row, col),
            float(height[view, row, col]),
            rotation,
            place_view=(float(views[view, 0]), float(views[view, 1])),
            pixel_size=self.pixel_size,
            n_rotations=self.n_rotations,
        )
