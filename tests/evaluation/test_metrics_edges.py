"""The metrics at their edges (the mutants of docs/mutation.md that test_metrics.py let live):
the interval's exact end points and refused inputs, the metric merged across processes, the
summary of episodes none of which ran."""

import math

import pytest
import torch

from nerf_transporter.evaluation.metrics import (
    SuccessRate,
    paired_comparison,
    strict_counts,
    strict_summary,
    summarize,
    wilson_interval,
)


def test_wilson_interval_ends_exactly_at_0_and_1_for_none_and_all():
    """0 of n has a lower bound of exactly 0, n of n an upper bound of exactly 1 (the formula's
    rounding would leave 1e-17 or 0.9999999999999999, which a cell would print and store)."""
    for episodes in range(1, 101):
        assert wilson_interval(0, episodes)[0] == 0.0, episodes
        assert wilson_interval(episodes, episodes)[1] == 1.0, episodes
        assert (
            wilson_interval(0, episodes)[1] > 0.0 and wilson_interval(episodes, episodes)[0] < 1.0
        )


def test_wilson_interval_refuses_successes_without_episodes_and_a_certain_confidence():
    with pytest.raises(ValueError, match="invalid counts: 1 successes out of 0 episodes"):
        wilson_interval(1, 0)
    for confidence in (0.0, 1.0):
        with pytest.raises(ValueError, match="confidence must lie in"):
            wilson_interval(5, 10, confidence)


def test_paired_comparison_counts_each_kind_of_seed():
    first = {1: True, 2: True, 3: False, 4: False, 5: True, 9: True}
    second = {1: True, 2: False, 3: True, 4: False, 5: True, 7: False}
    assert paired_comparison(first, second) == {
        "seeds": 5,
        "both": 2,
        "first_only": 1,
        "second_only": 1,
        "neither": 1,
        "p_value": 1.0,  # one discordant seed each way
    }
    with pytest.raises(ValueError) as refused:
        paired_comparison({1: True}, {2: True})
    assert str(refused.value) == "the two methods share no seeds"


def test_success_rate_merges_across_processes_by_summing():
    """What DDP does with the metric of each rank: its counts add up."""
    first, second = SuccessRate(), SuccessRate()
    first.update([True, False])
    second.update([True, True, False])
    first.merge_state(second)
    assert first.counts() == (3, 5)
    assert first.compute().item() == pytest.approx(0.6)


def test_success_rate_takes_rewards_and_a_single_episode():
    metric = SuccessRate()
    metric.update(torch.tensor([1.0, 0.0, 1.0]))  # rewards: any non-zero is a success
    assert metric.counts() == (2, 3)
    single = SuccessRate()
    single.update(True)
    assert single.compute().item() == 1.0


def test_strict_figures_leave_erred_episodes_out():
    ran = [{"seed": 1, "success": True, "strict_success": True, "error": None}]
    erred = [{"seed": 3, "success": False, "strict_success": None, "error": "RuntimeError: x"}]
    assert strict_counts(ran + erred) == (1, 1)
    summary = summarize(ran + erred)
    assert (summary["strict_successes"], summary["strict_success_rate"]) == (1, 1.0)
    assert summary["confidence"] == 0.95 and summary["erred_seeds"] == [3]


def test_a_summary_of_episodes_none_of_which_ran_has_no_rate():
    erred = [{"seed": 3, "success": False, "strict_success": None, "error": "RuntimeError: x"}]
    summary = summarize(erred)
    assert (summary["episodes"], summary["errors"]) == (0, 1)
    assert summary["success_rate"] is None and summary["strict_success_rate"] is None
    assert (summary["ci_low"], summary["ci_high"]) == (0.0, 1.0)
    assert strict_summary([])["strict_success_rate"] is None
    assert not math.isnan(summary["ci_high"])
