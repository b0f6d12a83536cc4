"""Which checkpoint `evaluate-checkpoints` names the best, among records that differ."""

from nerf_transporter.experiments.checkpoints import best_record


def _record(step: int, successes: int, episodes: int = 10, errors: int = 0) -> dict:
    rate = successes / episodes if episodes else None
    return {
        "checkpoint": f"step{step}.ckpt",
        "global_step": step,
        "episodes": episodes,
        "successes": successes,
        "success_rate": rate,
        "errors": errors,
    }


def test_the_highest_rate_wins_whatever_its_step():
    records = [_record(2, 3), _record(4, 7), _record(6, 5)]
    assert best_record(records)["checkpoint"] == "step4.ckpt"


def test_among_equal_rates_the_latest_wins():
    records = [_record(6, 7), _record(2, 7), _record(4, 5)]
    assert best_record(records)["checkpoint"] == "step6.ckpt"


def test_an_evaluation_with_erred_episodes_or_none_that_ran_is_never_the_best():
    records = [_record(2, 4), _record(4, 9, errors=1), _record(6, 0, episodes=0, errors=10)]
    assert best_record(records)["checkpoint"] == "step2.ckpt"
    assert best_record(records[1:]) is None
    assert best_record([]) is None
