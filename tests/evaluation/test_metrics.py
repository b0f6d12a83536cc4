"""Success-rate metric and the 95% Wilson score interval."""

import math

import pytest
import torch

from nerf_transporter.evaluation.metrics import (
    STRICT_FIGURES,
    SuccessRate,
    paired_comparison,
    summarize,
    wilson_interval,
)


@pytest.mark.parametrize(
    ("successes", "episodes", "expected"),
    [
        # Newcombe (1998), Statistics in Medicine 17:857, Table I, method 3 (Wilson score)
        (81, 263, (0.2553, 0.3662)),
        (15, 148, (0.0624, 0.1605)),
        (0, 20, (0.0, 0.1611)),
        (1, 29, (0.0061, 0.1718)),
    ],
)
def test_wilson_interval_matches_published_values(successes, episodes, expected):
    low, high = wilson_interval(successes, episodes)
    assert low == pytest.approx(expected[0], abs=5e-5)
    assert high == pytest.approx(expected[1], abs=5e-5)


def test_wilson_interval_is_symmetric_and_bounded():
    low, high = wilson_interval(7, 10)
    mirrored = wilson_interval(3, 10)
    assert low == pytest.approx(1 - mirrored[1])
    assert high == pytest.approx(1 - mirrored[0])
    assert wilson_interval(10, 10)[1] == pytest.approx(1.0)
    assert wilson_interval(0, 0) == (0.0, 1.0)


def test_wilson_interval_rejects_impossible_counts():
    with pytest.raises(ValueError, match="invalid counts"):
        wilson_interval(5, 3)
    with pytest.raises(ValueError, match="confidence"):
        wilson_interval(1, 3, confidence=1.5)


def test_success_rate_metric_accumulates_and_resets():
    metric = SuccessRate()
    metric.update([True, False, True])
    metric.update(torch.tensor([False]))
    assert metric.compute().item() == pytest.approx(0.5)
    assert metric.counts() == (2, 4)
    metric.reset()
    with pytest.warns(UserWarning, match="before the ``update``"):
        assert math.isnan(metric.compute().item())


def test_summarize_counts_failure_reasons_and_keeps_errors_out_of_the_rate():
    def record(seed, outcome, reason=None):
        return {
            "seed": seed,
            "outcome": outcome,
            "success": outcome == "success",
            "failure": reason if outcome == "failure" else None,
            "error": reason if outcome == "error" else None,
        }

    summary = summarize(
        [
            record(1, "failure", "unreachable"),
            record(3, "success"),
            record(5, "error", "observation raised OSError: disk full"),
            record(7, "failure", "unreachable"),
        ]
    )
    # the erred episode is not a failure of the policy: 1 success out of the 3 that ran
    assert (summary["episodes"], summary["successes"]) == (3, 1)
    assert summary["success_rate"] == pytest.approx(1 / 3)
    assert summary["failures"] == {"unreachable": 2}
    assert summary["ci_low"] < 1 / 3 < summary["ci_high"]
    assert summary["errors"] == 1 and summary["erred_seeds"] == [5]
    assert summary["error_reasons"] == {"observation raised OSError: disk full": 1}


def test_summarize_gives_the_strict_rate_beside_the_table_s_and_none_without_it():
    def record(seed, success, strict, error=None):
        return {"seed": seed, "success": success, "strict_success": strict, "error": error}

    summary = summarize(
        [
            record(1, True, True),
            record(3, True, False),  # the anchor's reward, but off the strict 6-DoF pose
            record(5, False, False),
            record(7, False, None, error="observation raised OSError: disk full"),
        ]
    )
    assert (summary["successes"], summary["strict_successes"], summary["episodes"]) == (2, 1, 3)
    assert summary["strict_success_rate"] == pytest.approx(1 / 3)
    assert (summary["strict_ci_low"], summary["strict_ci_high"]) == wilson_interval(1, 3)
    # a record that ran without the strict check (written before it was recorded) is no failure:
    # there is no strict rate at all
    old = {"seed": 9, "success": True, "error": None}
    legacy = summarize([record(1, True, True), old])
    assert legacy["success_rate"] == 1.0
    assert [legacy[key] for key in STRICT_FIGURES] == [None] * 4
    assert summarize([old])["strict_success_rate"] is None


def test_paired_comparison_counts_common_seeds_and_gives_the_exact_mcnemar_p():
    first = {seed: seed < 10 for seed in range(20)} | {99: True}  # seed 99: first only, not paired
    second = {seed: False for seed in range(20)}
    result = paired_comparison(first, second)
    assert (result["seeds"], result["both"], result["first_only"]) == (20, 0, 10)
    assert (result["second_only"], result["neither"]) == (0, 10)
    assert result["p_value"] == pytest.approx(2 / 2**10)  # 10 of 10 discordant seeds one way
    same = paired_comparison(second, second)
    assert same["p_value"] == 1.0 and same["neither"] == 20
    # 16 vs 12 discordant seeds: sum of C(28, k) for k <= 12, doubled, over 2^28
    tail = sum(math.comb(28, k) for k in range(13)) / 2**28
    mixed = paired_comparison({k: k < 16 for k in range(28)}, {k: k >= 16 for k in range(28)})
    assert mixed["p_value"] == pytest.approx(2 * tail)
    with pytest.raises(ValueError, match="share no seeds"):
        paired_comparison({1: True}, {2: True})
