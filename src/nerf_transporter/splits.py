"""Episode seeds per split: train even, test odd (both below 10^6), validation from 10^6 on."""

from __future__ import annotations

SPLITS = ("train", "validation", "test")
VALIDATION_OFFSET = 1_000_000


def split_seed(split: str, index: int) -> int:
    """Seed of the `index`-th episode of `split`."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(SPLITS)}")
    if index < 0 or (split != "validation" and 2 * index + 1 >= VALIDATION_OFFSET):
        raise ValueError(f"episode index {index} is out of range for split {split!r}")
    if split == "train":
        return 2 * index
    if split == "test":
        return 2 * index + 1
    return VALIDATION_OFFSET + index


def split_of_seed(seed: int) -> str:
    if seed >= VALIDATION_OFFSET:
        return "validation"
    return "train" if seed % 2 == 0 else "test"
