"""benchmarks/pick_scores.py: the attention's highest score on the object against the table."""

import numpy as np
import pytest
import torch
from torch import nn

from nerf_transporter import geometry
from nerf_transporter.evaluation.cache import ImageryCache
from nerf_transporter.evaluation.rollout import EvaluationSpec
from nerf_transporter.sim import make_env
from tests.helpers.benchmarks import load_benchmark


class HeightAttention(nn.Module):
    """An attention whose logit is a sign times the normalised height (input channel 3)."""

    def __init__(self, sign: float) -> None:
        super().__init__()
        self.sign = sign

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.sign * image[:, 3]


def test_an_attention_that_scores_height_sees_the_object_and_its_opposite_does_not():
    script = load_benchmark("pick_scores")
    env = make_env("stacking-kits")
    try:
        env.reset(seed=1)
        colour, height = env.render_orthographic(0.0, 0.0)
        ids, _ = env.render_segmentation_top_down()
        model = nn.Module()
        model.attention = HeightAttention(1.0)
        sees = script.highest_scores(model, colour, height, ids, env)
        model.attention = HeightAttention(-1.0)
        blind = script.highest_scores(model, colour, height, ids, env)
    finally:
        env.close()
    assert sees[0] > sees[1]  # the shape stands above the table
    assert blind[0] < blind[1]
    scores = [
        {"seed": 1, "pick_on_table": True, "imagery": blind, "simulator": sees},
        {"seed": 3, "pick_on_table": False, "imagery": sees, "simulator": sees},
    ]
    rows = script.summary_rows(scores)
    assert len(rows) == 4
    assert rows[0].startswith("| picks on the empty table (1) | the cell's |")
    assert rows[0].endswith("| 1 |") and rows[1].endswith("| 0 |")
    assert rows[2].startswith("| the other scenes (1) | the cell's |") and rows[2].endswith("| 0 |")


def test_scenes_are_grouped_by_where_the_recorded_pick_lay(tmp_path):
    """One pick on the shape and one on the empty table; the cell's imagery read from the cache."""
    script = load_benchmark("pick_scores")
    spec = EvaluationSpec(task="stacking-kits", imagery="oracle", cache_dir=str(tmp_path))
    cache = ImageryCache(tmp_path)
    env = make_env("stacking-kits")
    episodes = []
    try:
        for seed, on_table in ((1, False), (3, True)):
            env.reset(seed=seed)
            colour, height = env.render_orthographic(0.0, 0.0)
            imagery = {"colour": colour[None], "height": height[None], "views": np.zeros((1, 2))}
            cache.save("stacking-kits", "normal", seed, spec.imagery_key(), imagery)
            table = geometry.BOUNDS[:, 0] + 20 * geometry.PIXEL_SIZE
            pick = table if on_table else env.task.object_pose(env)[0]
            action = {"pick": [*pick[:2], 0.0, 0.0, 0.0, 0.0, 1.0], "place": [0.0] * 6 + [1.0]}
            episodes.append({"seed": seed, "success": False, "error": None, "action": action})
    finally:
        env.close()
    model = nn.Module()
    model.attention = HeightAttention(1.0)
    cell = {"task": "stacking-kits", "setting": "normal", "episode_results": episodes}
    scores = script.scene_scores(cell, model, spec, cache)
    assert [(s["seed"], s["pick_on_table"]) for s in scores] == [(1, False), (3, True)]
    # the cached imagery is the simulator's render here: both columns agree
    assert all(s["imagery"] == s["simulator"] for s in scores)
    cell["episode_results"].append(episodes[0] | {"seed": 5})  # not in the cache
    with pytest.raises(FileNotFoundError, match="seed 5's imagery is not in the cache"):
        script.scene_scores(cell, model, spec, cache)
