"""`form2fit`: pick and place affordances plus descriptor matching for the rotation."""

from __future__ import annotations

from typing import Any

import torch

from nerf_transporter.data.labels import action_from_labels
from nerf_transporter.methods.base import (
    Action,
    Batch,
    ImageMethod,
    heightmap_tensors,
    overlay,
    softmax_map,
)
from nerf_transporter.models import (
    Form2FitNets,
    pixel_cross_entropy,
    rotation_contrastive_loss,
    unravel_argmax,
)


class Form2Fit(ImageMethod):
    """Independent pick and place heatmaps on the heightmap; yaw bin by descriptor distance."""

    name = "form2fit"
    input_kind = "heightmap"

    def __init__(self, descriptor_dim: int = 16, margin: float = 1.0, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.margin = margin
        self.nets = Form2FitNets(
            6, self.n_rotations, self.crop_size, self.width, descriptor_dim, self.attention_fill()
        )

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        image = batch["image"]
        pick_loss = pixel_cross_entropy(self.nets.pick(image), batch["pick_pixel"])
        place_loss = pixel_cross_entropy(self.nets.place(image), batch["place_pixel"])
        distances = self.nets.rotation_distances(image, batch["pick_pixel"], batch["place_pixel"])
        match_loss = rotation_contrastive_loss(distances, batch["rotation_bin"], self.margin)
        return {
            "loss": pick_loss + place_loss + match_loss,
            "pick_loss": pick_loss,
            "place_loss": place_loss,
            "match_loss": match_loss,
        }

    def heatmaps(self, batch: Batch) -> dict[str, torch.Tensor]:
        image = batch["image"][:1]
        return {
            "pick": overlay(
                image[0], softmax_map(self.nets.pick(image)[0]), batch["pick_pixel"][0], "pick"
            ),
            "place": overlay(
                image[0], softmax_map(self.nets.place(image)[0]), batch["place_pixel"][0], "place"
            ),
        }

    @torch.no_grad()
    def act(self, observation: dict[str, Any]) -> Action:
        image, height = heightmap_tensors(observation, self.pixel_size, self.device)
        pick = unravel_argmax(self.nets.pick(image)[0])
        place = unravel_argmax(self.nets.place(image)[0])
        distances = self.nets.rotation_distances(
            image,
            torch.tensor([pick], device=self.device),
            torch.tensor([place], device=self.device),
        )
        rotation = int(distances[0].argmin())
        return action_from_labels(
            pick,
            float(height[pick]),
            place,
            float(height[place]),
            rotation,
            pixel_size=self.pixel_size,
            n_rotations=self.n_rotations,
        )
