"""Success rate of closed-loop episodes: a torchmetrics metric, its Wilson score interval, the
rate as the results table writes it (`cell`), and the paired comparison of two methods on the same
seeds."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping
from typing import Any

import torch
from scipy.stats import binomtest, norm
from torchmetrics import Metric

CONFIDENCE = 0.95  # the confidence of every interval a record states (the report's "95% Wilson")


def wilson_interval(
    successes: int, episodes: int, confidence: float = CONFIDENCE
) -> tuple[float, float]:
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


def paired_comparison(first: Mapping[int, bool], second: Mapping[int, bool]) -> dict[str, Any]:
    """Two methods' outcomes (seed -> success) on their common seeds: how many seeds both, only the
    first, only the second and neither succeeded on, and the exact McNemar p-value (two-sided
    binomial test of the seeds only one succeeded on)."""
    seeds = sorted(set(first) & set(second))
    if not seeds:
        raise ValueError("the two methods share no seeds")
    counts = Counter((bool(first[seed]), bool(second[seed])) for seed in seeds)
    first_only, second_only = counts[(True, False)], counts[(False, True)]
    discordant = first_only + second_only
    return {
        "seeds": len(seeds),
        "both": counts[(True, True)],
        "first_only": first_only,
        "second_only": second_only,
        "neither": counts[(False, False)],
        "p_value": binomtest(first_only, discordant, 0.5).pvalue if discordant else 1.0,
    }


def cell(record: dict) -> str:
    """'rate% (n, low-high)' with percentages rounded to integers; '; k erred' appended when
    episodes erred (they are not in n)."""
    episodes, errors = record["episodes"], record.get("errors", 0)
    erred = f"; {errors} erred" if errors else ""
    if episodes == 0:
        return f"- (0{erred})"
    rate = round(100 * record["successes"] / episodes)
    low, high = round(100 * record["ci_low"]), round(100 * record["ci_high"])
    return f"{rate}% ({episodes}, {low}-{high}{erred})"


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


# the figures of the strict 6-DoF check in a summary (results file, cell)
STRICT_FIGURES = ("strict_successes", "strict_success_rate", "strict_ci_low", "strict_ci_high")


def strict_counts(episodes: Iterable[Mapping[str, Any]]) -> tuple[int, int] | None:
    """(strict successes, episodes) of the episode records that ran, by their `strict_success`
    (the project's stricter 6-DoF check); None where one that ran has none (a record written
    before it was recorded), so that a missing check never counts as a failure."""
    ran = [record for record in episodes if record.get("error") is None]
    if any(record.get("strict_success") is None for record in ran):
        return None
    return sum(bool(record["strict_success"]) for record in ran), len(ran)


def strict_summary(episodes: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """`strict_successes`, `strict_success_rate` and its 95% Wilson interval (`strict_ci_low`,
    `strict_ci_high`) over the episodes that ran; all None where `strict_counts` is None."""
    counts = strict_counts(episodes)
    if counts is None:
        return dict.fromkeys(STRICT_FIGURES)
    successes, ran = counts
    low, high = wilson_interval(successes, ran)
    return {
        "strict_successes": successes,
        "strict_success_rate": successes / ran if ran else None,
        "strict_ci_low": low,
        "strict_ci_high": high,
    }


def summarize(episodes: Iterable[Mapping[str, Any]]) -> dict:
    """Figures of episode records (`EpisodeResult.to_json()`), as JSON-ready values.

    The rate and its 95% Wilson interval are over the episodes that ran (successes and failures);
    erred episodes are counted apart, with their seeds and reasons, and the tally of failure
    reasons says why the robot missed. The same figures of the stricter 6-DoF check follow
    (`strict_summary`: None where a record that ran lacks it).
    """
    episodes = list(episodes)
    ran = [record for record in episodes if record.get("error") is None]
    erred = [record for record in episodes if record.get("error") is not None]
    successes = sum(bool(record["success"]) for record in ran)
    low, high = wilson_interval(successes, len(ran))
    return {
        "episodes": len(ran),
        "successes": successes,
        "success_rate": successes / len(ran) if ran else None,
        "ci_low": low,
        "ci_high": high,
        "confidence": CONFIDENCE,
        **strict_summary(ran),
        "failures": dict(Counter(r["failure"] for r in ran if r.get("failure") is not None)),
        "errors": len(erred),
        "erred_seeds": sorted(int(record["seed"]) for record in erred),
        "error_reasons": dict(Counter(record["error"] for record in erred)),
    }
