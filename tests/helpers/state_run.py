"""A gt_state_mlp trained for 2 steps on block-insertion, with a RavensDataModule attached: its
checkpoints are what the checkpoint tools (evaluate-checkpoints, export-pretrained) read."""

from pathlib import Path

import lightning.pytorch as pl
import torch
from lightning.pytorch.cli import LightningCLI
from torch.utils.data import DataLoader

from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.methods import Method
from nerf_transporter.sim import make_env


class StateBatches(torch.utils.data.Dataset):
    """Random (state, pick, place) samples with unit quaternions: enough to take optimiser steps."""

    def __init__(self, state_dim: int) -> None:
        generator = torch.Generator().manual_seed(0)
        self.state = torch.randn(4, state_dim, generator=generator)
        self.poses = torch.randn(4, 2, 7, generator=generator)
        self.poses[..., 3:] = torch.nn.functional.normalize(self.poses[..., 3:], dim=-1)

    def __len__(self) -> int:
        return 4

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        pick, place = self.poses[index]
        return {"state": self.state[index], "pick": pick, "place": place}


def trained_state_mlp(data_dir: Path) -> pl.Trainer:
    """The trainer after 2 steps; `trainer.save_checkpoint(path)` writes a run's checkpoint."""
    state_dim = make_env("block-insertion").task.state_dim()
    cli = LightningCLI(
        Method,
        RavensDataModule,
        subclass_mode_model=True,
        run=False,
        save_config_callback=None,
        args={
            "model": {"class_path": "GTStateMLP", "init_args": {"state_dim": state_dim}},
            "data": {"task": "block-insertion", "imagery": "oracle", "data_dir": str(data_dir)},
            "trainer": {
                "max_steps": 2,
                "logger": False,
                "enable_progress_bar": False,
                # the caller saves the checkpoint it needs; none lands in the working directory
                "enable_checkpointing": False,
                "default_root_dir": str(data_dir),
            },
        },
    )
    cli.trainer.fit(cli.model, train_dataloaders=DataLoader(StateBatches(state_dim), batch_size=2))
    cli.trainer.datamodule = cli.datamodule  # its hyper-parameters go into the checkpoints
    return cli.trainer
