"""`transporter_se3`: Transporter-SE(2) plus regression of the place z, roll and pitch."""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F

from nerf_transporter.methods.base import Action, Batch, heightmap_tensors
from nerf_transporter.methods.transporter_se2 import TransporterSE2
from nerf_transporter.models import PoseRegression

Z_SCALE = 0.1  # metres per regressed unit of z, so that z, roll and pitch have similar ranges


class TransporterSE3(TransporterSE2):
    """SE(2) search for (pixel, yaw); Huber-loss heads for z, roll, pitch at the chosen placement."""

    name = "transporter_se3"
    input_kind = "heightmap"

    def __init__(self, regression_features: int = 8, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.regression = PoseRegression(
            6,
            self.n_rotations,
            self.crop_size,
            self.width,
            self.feature_channels,
            regression_features,
        )

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        losses = super().losses(batch)
        image = batch["image"]
        predicted = self.regression(
            image, batch["pick_pixel"], image, batch["place_pixel"], batch["rotation_bin"]
        )
        target = torch.stack(
            [batch["place_z"] / Z_SCALE, batch["place_roll"], batch["place_pitch"]], dim=1
        ).to(predicted)
        parts = F.huber_loss(predicted, target, reduction="none").mean(0)
        losses.update(z_loss=parts[0], roll_loss=parts[1], pitch_loss=parts[2])
        losses["loss"] = losses["loss"] + parts.sum()
        return losses

    @torch.no_grad()
    def act(self, observation: dict[str, Any]) -> Action:
        image, height = heightmap_tensors(observation, self.pixel_size, self.device)
        pick, rotation, place = self.predict_pick_place(image)
        z, roll, pitch = self.regression(
            image,
            torch.tensor([pick], device=self.device),
            image,
            torch.tensor([place], device=self.device),
            torch.tensor([rotation], device=self.device),
        )[0].tolist()
        return self.heightmap_action(height, pick, rotation, place, z * Z_SCALE, (roll, pitch))
