"""Episode seeds as a dataset: the test dataloader of `RavensDataModule` yields the first seeds of
the test split, one per batch, and the closed-loop test callback plays them
(`evaluation/testing.py`). Under DDP Lightning's distributed sampler gives each process its share.
"""

from __future__ import annotations

from torch.utils.data import DataLoader, Dataset

from nerf_transporter.splits import split_seed


class SeedDataset(Dataset):
    """The first `episodes` seeds of a split (`splits.split_seed`)."""

    def __init__(self, split: str, episodes: int) -> None:
        if episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {episodes}")
        split_seed(split, episodes - 1)  # validates the split name and the range
        self.split = split
        self.episodes = episodes

    def __len__(self) -> int:
        return self.episodes

    def __getitem__(self, index: int) -> int:
        return split_seed(self.split, index)


def seed_loader(split: str, episodes: int) -> DataLoader:
    """One seed per batch, in order (the test progress bar then counts episodes)."""
    return DataLoader(SeedDataset(split, episodes), batch_size=1, shuffle=False)
