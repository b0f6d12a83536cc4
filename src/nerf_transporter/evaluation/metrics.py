"""Success rate of closed-loop episodes: a torchmetrics metric and its Wilson score interval."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable

import torch
from scipy.stats import norm
from torchmetrics import Metric


def wilson_interval(successes: int, episodes: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion; (0, 1) when there are no episodes."""
    if episodes < 0 or not 0 <= successes <= max(episodes, 0):
        raise ValueError(f"invalid counts: {successes} successes out of {episodes} episodes")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    if episodes == 0:
        return 0.0, 1.0
    z = float(norm.ppf(0.5 + confidence / 2.0))
    rate = successes / episodes
    denominator = 1.0 + z * z / episodes
    centre = (rate + z * z / (2 * episodes)) / denominator
    half_width = (
        z
        * math.sqrt(rate * (1 - rate) / episodes + z * z / (4 * episodes * episodes))
        / denominator
    )
    low = 0.0 if successes == 0 else max(0.0, centre - half_width)
    high = 1.0 if successes == episodes else min(1.0, centre + half_width)
    return low, high


class SuccessRate(Metric):
    """Fraction of successful episodes; counts are summed across processes (DDP)."""

    is_differentiable = False
    higher_is_better = True
    full_state_update = False

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_state("successes", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("episodes", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")

    def update(self, success: torch.Tensor | bool | Iterable[bool]) -> None:
        outcome = torch.as_tensor(success, dtype=torch.bool, device=self.successes.device).flatten()
        self.successes += outcome.sum()
        self.episodes += outcome.numel()

    def counts(self) -> tuple[int, int]:
        """(successes, episodes) over all processes."""
        with self.sync_context():
            return int(self.successes), int(self.episodes)

    def compute(self) -> torch.Tensor:
        if self.episodes == 0:
            return torch.tensor(float("nan"))
        return self.successes.float() / self.episodes.float()


def summarize(successes: int, episodes: int, failures: Iterable[str | None] = ()) -> dict:
    """Rate, 95% Wilson interval, counts and the tally of failure reasons, as JSON-ready values."""
    low, high = wilson_interval(successes, episodes)
    return {
        "episodes": episodes,
        "successes": successes,
        "success_rate": successes / episodes if episodes else None,
        "ci_low": low,
        "ci_high": high,
        "confidence": 0.95,
        "failures": dict(Counter(reason for reason in failures if reason is not None)),
    }
