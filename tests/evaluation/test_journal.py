"""An interrupted evaluation resumes: its finished episodes are journalled as they end and taken,
not run again, by the next evaluation of the same identity, with the record a whole run gives."""

import json

import pytest

from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.evaluation.journal import EpisodeJournal
from nerf_transporter.evaluation.rollout import EpisodeResult
from nerf_transporter.evaluation.testing import evaluate_policy
from tests.evaluation.test_rollout import FixedPolicy

IDENTITY = {"checkpoint_sha256": "ab", "split": "test"}


def finished(seed, success=True):
    return EpisodeResult(seed=seed, success=success, failure=None if success else "missed")


def test_finished_episodes_are_read_back_and_erred_ones_left_to_run_again(tmp_path):
    journal = EpisodeJournal(tmp_path, IDENTITY)
    assert journal.finished([1, 3]) == {}
    journal.record(finished(1))
    journal.record(EpisodeResult.erred(3, "physics server died"))
    journal.record(finished(5, success=False))
    # a journal of another identity is another file, never read for this one
    assert EpisodeJournal(tmp_path, IDENTITY | {"split": "validation"}).finished([1]) == {}
    reread = EpisodeJournal(tmp_path, IDENTITY)
    assert reread.finished([1, 3, 5, 7]) == {1: finished(1), 5: finished(5, success=False)}
    assert reread.finished([5]) == {5: finished(5, success=False)}
    assert json.loads(reread.path.read_text().splitlines()[0]) == {"journal": IDENTITY}
    reread.remove()
    assert not reread.path.exists() and reread.finished([1]) == {}


def test_a_line_cut_short_is_dropped_and_a_damaged_journal_named(tmp_path):
    journal = EpisodeJournal(tmp_path, IDENTITY)
    journal.record(finished(1))
    with open(journal.path, "a") as file:
        file.write('{"seed": 3, "succ')  # the process was killed mid-write
    assert journal.finished([1, 3]) == {1: finished(1)}
    journal.record(finished(3))  # appended after the repaired end, readable
    assert set(journal.finished([1, 3])) == {1, 3}

    lines = journal.path.read_text().splitlines()
    journal.path.write_text("\n".join([lines[0], "not json", lines[2]]) + "\n")
    with pytest.raises(ValueError, match=f"{journal.path} is damaged at line 2"):
        journal.finished([1, 3])


class InterruptedPolicy(FixedPolicy):
    """FixedPolicy, stopped by the user (Ctrl-C) when asked for its `stop_at`-th action."""

    def __init__(self, stop_at=None):
        super().__init__()
        self.stop_at = stop_at

    def act(self, observation):
        if len(self.observations) + 1 == self.stop_at:
            raise KeyboardInterrupt
        return super().act(observation)


def test_an_interrupted_evaluation_resumes_with_the_record_of_a_whole_run(tmp_path):
    datamodule = RavensDataModule("block-insertion", imagery="oracle", data_dir=str(tmp_path))
    seeds = [1, 3]

    def evaluate(policy, journal_dir, **options):
        return evaluate_policy(
            policy,
            datamodule,
            seeds,
            split="test",
            workers=1,
            progress=False,
            cache_dir=None,
            journal_dir=journal_dir,
            **options,
        )

    journals = tmp_path / "journals"
    with pytest.raises(KeyboardInterrupt):
        evaluate(InterruptedPolicy(stop_at=2), journals)
    assert len(list(journals.glob("*.jsonl"))) == 1  # seed 1's episode was kept

    kept = []
    resuming = InterruptedPolicy()
    resumed = evaluate(resuming, journals, keep=kept.append)
    assert len(resuming.observations) == 1  # only seed 3 ran again
    assert resumed["resumed_episodes"] == 1 and kept == [resumed]
    assert not list(journals.glob("*.jsonl"))  # the record is kept, the journal gone

    whole = evaluate(InterruptedPolicy(), None)
    assert "resumed_episodes" not in whole

    def outcomes(record):
        return [
            {key: value for key, value in episode.items() if key != "timings"}
            for episode in record["episode_results"]
        ]

    assert [episode["seed"] for episode in resumed["episode_results"]] == seeds
    assert outcomes(resumed) == outcomes(whole)
    assert resumed["successes"] == whole["successes"] and resumed["episodes"] == 2
