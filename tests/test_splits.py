import pytest

from nerf_transporter.splits import SPLITS, split_of_seed, split_seed


def test_splits_are_disjoint_and_round_trip():
    seen = set()
    for split in SPLITS:
        seeds = {split_seed(split, i) for i in range(200)}
        assert not seeds & seen
        seen |= seeds
        assert all(split_of_seed(s) == split for s in seeds)


def test_unknown_split_names_valid_ones():
    with pytest.raises(ValueError, match="train, validation, test"):
        split_seed("val", 0)
