"""`transporter_se2`: attention and transport on the fused top-down RGB-D heightmap."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from nerf_transporter.data.labels import action_from_labels
from nerf_transporter.methods.base import (
    Action,
    AttentionTransportMethod,
    Batch,
    heightmap_tensors,
)
from nerf_transporter.models.transport import unravel_argmax


class TransporterSE2(AttentionTransportMethod):
    """Pick pixel, place pixel and yaw bin on one heightmap; place z from the heightmap, flat."""

    name = "transporter_se2"
    input_kind = "heightmap"

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        image = batch["image"]
        return self.pick_place_losses(image, image[:, None], batch)

    def heatmaps(self, batch: Batch) -> dict[str, torch.Tensor]:
        return self.pick_place_heatmaps(batch["image"], batch["image"], batch)

    def predict_pick_place(
        self, image: torch.Tensor
    ) -> tuple[tuple[int, int], int, tuple[int, int]]:
        """One heightmap input [1, 6, H, W] -> (pick pixel, rotation bin, place pixel)."""
        pick = self.predict_pick(image)
        logits = self.transport(image, torch.tensor([pick], device=self.device), image[:, None])
        rotation, row, col = unravel_argmax(logits[0, 0])
        return pick, rotation, (row, col)

    def heightmap_action(
        self,
        height: np.ndarray,
        pick: tuple[int, int],
        rotation: int,
        place: tuple[int, int],
        place_z: float | None = None,
        place_tilt: tuple[float, float] = (0.0, 0.0),
    ) -> Action:
        """Action from predicted labels; place z from the heightmap unless given."""
        return action_from_labels(
            pick,
            float(height[pick]),
            place,
            float(height[place]) if place_z is None else place_z,
            rotation,
            place_tilt=place_tilt,
            pixel_size=self.pixel_size,
            n_rotations=self.n_rotations,
        )

    @torch.no_grad()
    def act(self, observation: dict[str, Any]) -> Action:
        image, height = heightmap_tensors(observation, self.pixel_size, self.device)
        pick, rotation, place = self.predict_pick_place(image)
        return self.heightmap_action(height, pick, rotation, place)
