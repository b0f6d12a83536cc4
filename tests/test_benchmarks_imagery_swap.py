"""benchmarks/imagery_swap.py: a scene's views with one imagery's colour and the other's height."""

import numpy as np
import pytest

from nerf_transporter.evaluation.cache import ImageryCache
from nerf_transporter.evaluation.rollout import EvaluationSpec
from tests.helpers.benchmarks import load_benchmark

GRID = np.array([[0.0, 0.0], [0.1, 0.0]])


def views(level: int, grid: np.ndarray = GRID) -> dict[str, np.ndarray]:
    return {
        "colour": np.full((2, 4, 2, 3), level, dtype=np.uint8),
        "height": np.full((2, 4, 2), level / 100, dtype=np.float32),
        "views": grid,
    }


def test_the_swap_takes_colour_from_one_imagery_and_height_from_the_other(tmp_path):
    script = load_benchmark("imagery_swap")
    specs = {
        kind: EvaluationSpec("place-red-in-green", setting="challenging", imagery=kind)
        for kind in ("nerf", "oracle")
    }
    assert specs["nerf"].imagery_key() != specs["oracle"].imagery_key()
    source, target = ImageryCache(tmp_path / "cache"), ImageryCache(tmp_path / "swap")
    for kind, level in (("nerf", 10), ("oracle", 200)):
        source.save("place-red-in-green", "challenging", 1, specs[kind].imagery_key(), views(level))
    script.build_swap_cache(specs, "oracle", "nerf", [1], source, target)
    swapped = target.load("place-red-in-green", "challenging", 1, specs["nerf"].imagery_key())
    assert (swapped["colour"] == 200).all() and np.allclose(swapped["height"], 0.1)
    with pytest.raises(FileNotFoundError, match="no oracle imagery .* seed 3 .* --imagery oracle"):
        script.build_swap_cache(specs, "oracle", "nerf", [3], source, target)
    with pytest.raises(ValueError, match="different view grids"):
        script.swapped_views(views(1), views(2, GRID * 2))


def test_the_colour_half_can_be_blurred_alone(tmp_path):
    """`--colour-blur`: the swap test's control blurs the simulator's colour, height untouched."""
    script = load_benchmark("imagery_swap")
    specs = {
        kind: EvaluationSpec("place-red-in-green", setting="challenging", imagery=kind)
        for kind in ("nerf", "oracle")
    }
    edge = views(0)
    edge["colour"][:, :2] = 200  # a step between rows 1 and 2 of every view
    source, target = ImageryCache(tmp_path / "cache"), ImageryCache(tmp_path / "swap")
    source.save("place-red-in-green", "challenging", 1, specs["oracle"].imagery_key(), edge)
    script.build_swap_cache(specs, "oracle", "oracle", [1], source, target, colour_blur=1.0)
    swapped = target.load("place-red-in-green", "challenging", 1, specs["nerf"].imagery_key())
    step = swapped["colour"][:, :, 0, 0].astype(int)  # each view's column down its rows
    assert (np.diff(step, axis=1) <= 0).all() and (step[:, 1:3] > 0).all()
    assert (step[:, 1:3] < 200).all() and np.array_equal(swapped["height"], edge["height"])
    assert script.blurred(edge["colour"], 0.0) is edge["colour"]
    with pytest.raises(ValueError, match="at least 0 pixels"):
        script.blurred(edge["colour"], -1.0)
