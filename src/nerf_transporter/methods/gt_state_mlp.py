"""`gt_state_mlp`: an MLP from ground-truth object and target poses to pick and place poses."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from nerf_transporter import geometry as g
from nerf_transporter.methods.base import Action, Batch, Method
from nerf_transporter.models import StateMLP, columns_from_rotation, rotation_from_columns
from nerf_transporter.models.mlp import quat_to_matrix

POSITION_SCALE = 0.1  # metres per regressed unit, positions relative to the workspace centre


class GTStateMLP(Method):
    """Regresses (position, rotation) of pick and place from the state vector.

    `state_dim` is the task's state length; left unset, it is taken from the trainer's DataModule
    (`RavensDataModule.state_dim`, known without loading data) when training starts, and stored in
    the checkpoint's hyperparameters.
    """

    name = "gt_state_mlp"
    input_kind = "state"

    def __init__(
        self,
        lr: float = 1e-3,
        state_dim: int | None = None,
        hidden: int = 128,
        layers: int = 3,
        **kwargs: Any,
    ) -> None:
        super().__init__(lr=lr, **kwargs)
        self.hidden = hidden
        self.layers = layers
        self.mlp = StateMLP(state_dim, hidden, layers) if state_dim is not None else None

    def configure_model(self) -> None:
        if self.mlp is not None:
            return
        state_dim = getattr(getattr(self.trainer, "datamodule", None), "state_dim", None)
        if state_dim is None:
            raise ValueError(
                "gt_state_mlp needs the state length: set model.init_args.state_dim or train "
                "with a DataModule that has `state_dim`"
            )
        state_dim = int(state_dim)
        self.hparams["state_dim"] = state_dim
        self.mlp = StateMLP(state_dim, self.hidden, self.layers)

    def _targets(self, pose: torch.Tensor) -> torch.Tensor:
        """[B, 7] (xyz, quat_xyzw) -> [B, 9] regression targets."""
        centre = pose.new_tensor(g.WORKSPACE_CENTER)
        position = (pose[:, :3] - centre) / POSITION_SCALE
        return torch.cat([position, columns_from_rotation(quat_to_matrix(pose[:, 3:]))], dim=1)

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        predicted = self.mlp(batch["state"].float())
        target = torch.stack([self._targets(batch["pick"]), self._targets(batch["place"])], dim=1)
        target = target.to(predicted)
        position_loss = F.mse_loss(predicted[..., :3], target[..., :3])
        rotation_loss = F.mse_loss(predicted[..., 3:], target[..., 3:])
        return {
            "loss": position_loss + rotation_loss,
            "position_loss": position_loss,
            "rotation_loss": rotation_loss,
        }

    @torch.no_grad()
    def act(self, observation: dict[str, Any]) -> Action:
        if "state" not in observation:
            raise ValueError(f"observation has no 'state' entry (keys: {sorted(observation)})")
        state = torch.as_tensor(np.asarray(observation["state"]), dtype=torch.float32)
        expected = self.hparams["state_dim"]
        if state.shape != (expected,):
            raise ValueError(
                f"state has shape {tuple(state.shape)}, this model expects ({expected},)"
            )
        output = self.mlp(state[None].to(self.device))[0].double().cpu()
        poses = []
        for pose in output:
            position = pose[:3].numpy() * POSITION_SCALE + g.WORKSPACE_CENTER
            rotation = rotation_from_columns(pose[3:]).numpy()
            poses.append((position, g.matrix_to_quat(rotation)))
        return {"pick": poses[0], "place": poses[1]}
