"""benchmarks/pick_scores.py: the attention's highest score on the object against the table."""

import torch
from torch import nn

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
        {"seed": 1, "missed_pick": True, "imagery": blind, "simulator": sees},
        {"seed": 3, "missed_pick": False, "imagery": sees, "simulator": sees},
    ]
    rows = script.summary_rows(scores)
    assert len(rows) == 4
    assert rows[0].startswith("| picks that touched nothing (1) | the cell's |")
    assert rows[0].endswith("| 1 |") and rows[1].endswith("| 0 |")
    assert rows[2].startswith("| the other scenes (1) | the cell's |") and rows[2].endswith("| 0 |")
