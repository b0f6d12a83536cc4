"""One closed-loop episode: failures and errors are recorded apart, never raised; imagery is cached
per seed, and a damaged cache entry is rebuilt."""

import numpy as np
import pytest
import torch

from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.data.observation import SceneSpec
from nerf_transporter.evaluation import rollout
from nerf_transporter.evaluation.rollout import EpisodeResult, EvaluationSpec, Evaluator
from nerf_transporter.evaluation.testing import evaluate_policy
from nerf_transporter.sim import make_env

UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])
ACTION = {
    "pick": (np.array([0.3514, -0.2260, 0.04]), UPRIGHT),  # on block-insertion seed 3's block
    "place": (np.array([0.5, 0.2, 0.02]), UPRIGHT),
}


class FixedPolicy(torch.nn.Module):
    """Always the same action; remembers the observations it was given."""

    def __init__(self, input_kind="state", error=None):
        super().__init__()
        self.input_kind = input_kind
        self.error = error
        self.observations = []
        self.modes = []

    def act(self, observation):
        self.observations.append(observation)
        self.modes.append(self.training)
        if self.error is not None:
            raise self.error
        return ACTION


class CrashingStepFactory:
    """make_env, except that the first environment's `step` raises like a dead physics server."""

    def __init__(self):
        self.built = 0

    def __call__(self, task, setting, **options):
        env = make_env(task, setting, **options)
        self.built += 1
        if self.built == 1:

            def crash(action):
                raise RuntimeError("Not connected to physics server.")

            env.step = crash
        return env


class JudgedEnv:
    """Stands in for the simulator (no PyBullet): every step ends with the info it was given, or
    raises `raises`."""

    frame_callback = None

    def __init__(self, info, raises=None):
        self.info, self.raises = info, raises

    def reset(self, seed):
        return {"state": np.zeros(14, dtype=np.float32)}, {}

    def step(self, action):
        if self.raises is not None:
            raise self.raises
        return None, float(self.info["success"]), True, False, dict(self.info)

    def close(self):
        pass


# the anchor's reward is won, the project's stricter 6-DoF check (1 cm here) is not
JUDGED = {
    "success": True,
    "failure": None,
    "position_error": 0.012,
    "tilt_error": 0.0,
    "yaw_error": 0.0,
    "strict_success": False,
    "strict_errors": {"position_error": 0.012, "tilt_error": 0.0, "yaw_error": 0.0},
}


def judged_episode(policy, **env_options):
    spec = EvaluationSpec(task="block-insertion", imagery="oracle", cache_dir=None)
    with Evaluator(spec, lambda task, setting, **_: JudgedEnv(JUDGED, **env_options)) as evaluator:
        return evaluator.run_episode(policy, 1)


def test_an_episode_records_the_strict_check_beside_the_reward():
    result = judged_episode(FixedPolicy())
    assert result.outcome == "success" and result.strict_success is False
    record = result.to_json()
    assert (record["success"], record["strict_success"]) == (True, False)
    assert record["strict_errors"] == JUDGED["strict_errors"]
    assert EpisodeResult.from_json(record) == result
    # a simulator fault during the motion fails the strict check too; an erred episode has none
    faulted = judged_episode(FixedPolicy(), raises=RuntimeError("Not connected"))
    assert faulted.outcome == "failure" and faulted.strict_success is False
    erred = judged_episode(FixedPolicy(error=ValueError("no valid pick pixel")))
    assert erred.outcome == "error" and erred.to_json()["strict_success"] is None
    # a record written before the strict check was recorded still loads, without one
    old = {"outcome": "success", "seed": 1, "success": True, "failure": None, "error": None}
    assert EpisodeResult.from_json(old).strict_success is None


def test_an_episode_whose_simulation_raises_is_a_failure_and_the_run_goes_on():
    factory = CrashingStepFactory()
    policy = FixedPolicy()
    with Evaluator(EvaluationSpec(task="block-insertion", imagery="oracle"), factory) as evaluator:
        results = evaluator.run(policy, [1, 3])
    crashed, after = results
    assert crashed.seed == 1 and not crashed.success and crashed.outcome == "failure"
    assert crashed.failure == (
        "simulator fault during the robot's motion "
        "(step raised RuntimeError: Not connected to physics server.)"
    )
    assert crashed.error is None
    assert crashed.action is not None and len(crashed.action["pick"]) == 7
    # the broken environment was replaced and the next episode ran to its judgement
    assert factory.built == 2
    assert after.seed == 3 and "raised" not in (after.failure or "")
    assert set(after.timings) >= {"reset_s", "act_s", "step_s", "total_s"}
    # a policy that misses says by how much
    assert after.failure == "task not achieved"
    assert set(after.pose_error) == {"position_error", "tilt_error", "yaw_error"}
    assert after.failure_text().startswith("the object did not end at the target pose (position")
    assert after.to_json()["pose_error"] == after.pose_error


def test_a_policy_that_raises_is_an_error_not_a_robot_failure():
    policy = FixedPolicy(error=ValueError("no valid pick pixel"))
    policy.train()
    with Evaluator(EvaluationSpec(task="block-insertion", imagery="oracle")) as evaluator:
        result = evaluator.run_episode(policy, 1)
    assert not result.success and result.outcome == "error" and result.failure is None
    assert result.error == "act raised ValueError: no valid pick pixel"
    assert result.to_json()["outcome"] == "error"
    assert result.action is None
    assert policy.modes == [False] and policy.training  # acted in eval mode, training mode restored


def test_unknown_input_kind_is_refused():
    with (
        Evaluator(EvaluationSpec(task="block-insertion", imagery="oracle")) as evaluator,
        pytest.raises(ValueError, match="input_kind"),
    ):
        evaluator.run_episode(FixedPolicy(input_kind="pointcloud"), 1)


def test_imagery_is_cached_by_seed_and_reused(tmp_path):
    spec = EvaluationSpec(
        task="block-insertion", imagery="oracle", pixel_size=0.0125, cache_dir=str(tmp_path)
    )
    policy = FixedPolicy(input_kind="imagery")
    with Evaluator(spec) as evaluator:
        first = evaluator.run_episode(policy, 1)
        second = evaluator.run_episode(policy, 1)
    assert (first.imagery_cached, second.imagery_cached) == (False, True)
    fresh, cached = (obs["imagery"] for obs in policy.observations)
    assert fresh["colour"].shape == (49, 80, 40, 3) and fresh["height"].shape == (49, 80, 40)
    for key in ("colour", "height", "views"):
        np.testing.assert_array_equal(fresh[key], cached[key])
    assert len(list(tmp_path.rglob("*.npz"))) == 1
    # a different imagery config is a different cache entry
    other = EvaluationSpec(task="block-insertion", imagery="oracle", pixel_size=0.025)
    assert other.imagery_key() != spec.imagery_key()


def test_imagery_cached_ahead_is_the_episodes_own_and_is_read_by_it(tmp_path):
    """A NeRF fit cached before the episode (cache-imagery) equals the one the episode makes."""
    scene = SceneSpec("block-insertion", "normal", "nerf", 0.0125, 6, (60, 80), {"iterations": 30})
    ahead, inline = (EvaluationSpec(scene=scene, cache_dir=str(tmp_path / n)) for n in "ai")
    rng = torch.random.get_rng_state()
    with Evaluator(ahead) as evaluator:
        assert (evaluator.cache_imagery(1), evaluator.cache_imagery(1)) == (True, False)
        assert torch.equal(torch.random.get_rng_state(), rng)
        assert evaluator.run_episode(FixedPolicy(input_kind="imagery"), 1).imagery_cached
    with Evaluator(inline) as evaluator:
        assert evaluator.run_episode(FixedPolicy(input_kind="imagery"), 1).imagery_cached is False
    (built_ahead,), (built_inline,) = (sorted((tmp_path / n).rglob("*.npz")) for n in "ai")
    assert built_ahead.relative_to(tmp_path / "a") == built_inline.relative_to(tmp_path / "i")
    with np.load(built_ahead) as first, np.load(built_inline) as second:
        for key in ("colour", "height", "views"):
            np.testing.assert_array_equal(first[key], second[key])
    with pytest.raises(ValueError, match="needs an imagery cache"):
        Evaluator(EvaluationSpec(scene=scene, cache_dir=None)).cache_imagery(1)


def test_a_rendering_option_is_cached_from_the_same_fit_as_an_evaluation_builds_it(tmp_path):
    """`cache_imagery(seed, [{"depth": "median"}])` fits once and caches both renderings, the
    median one under the key, and with the arrays, of an evaluation that builds it itself."""
    # 60 iterations: enough density that the median and expected heights differ
    scene = SceneSpec("block-insertion", "normal", "nerf", 0.0125, 6, (60, 80), {"iterations": 60})
    median = scene.rendered_with({"depth": "median"})
    with Evaluator(EvaluationSpec(scene=scene, cache_dir=str(tmp_path))) as evaluator:
        # the default named again ({"depth": "expected"}) is the default's entry, not a third
        assert evaluator.cache_imagery(1, [{"depth": "median"}, {"depth": "expected"}]) == 2
        assert evaluator.cache_imagery(1, [{"depth": "median"}]) == 0
    policy = FixedPolicy(input_kind="imagery")
    with Evaluator(EvaluationSpec(scene=median, cache_dir=None)) as evaluator:
        evaluator.run_episode(policy, 1)
    built = policy.observations[0]["imagery"]
    (median_entry,) = tmp_path.rglob(f"1-{EvaluationSpec(scene=median).imagery_key()}.npz")
    (expected_entry,) = tmp_path.rglob(f"1-{EvaluationSpec(scene=scene).imagery_key()}.npz")
    with np.load(median_entry) as cached, np.load(expected_entry) as expected:
        for name in ("colour", "height", "views"):
            np.testing.assert_array_equal(cached[name], built[name])
        np.testing.assert_array_equal(expected["colour"], built["colour"])  # one fit
        assert not np.array_equal(expected["height"], built["height"])  # two renderings
    with pytest.raises(ValueError, match="iterations changes the fit, not its rendering"):
        scene.rendered_with({"iterations": 60})


def oracle_imagery_spec(cache_dir):
    return EvaluationSpec(
        task="block-insertion", imagery="oracle", pixel_size=0.0125, cache_dir=str(cache_dir)
    )


def test_a_corrupt_cache_entry_is_deleted_rebuilt_and_the_episode_counts(tmp_path, caplog):
    policy = FixedPolicy(input_kind="imagery")
    with Evaluator(oracle_imagery_spec(tmp_path)) as evaluator:
        first = evaluator.run_episode(policy, 1)
        (entry,) = tmp_path.rglob("*.npz")
        entry.write_bytes(entry.read_bytes()[:200])  # truncated: a BadZipFile on load
        again = evaluator.run_episode(policy, 1)
    assert again.error is None and again.outcome == first.outcome
    assert again.imagery_cached is False  # rebuilt, not read
    assert "corrupt imagery cache file" in caplog.text
    fresh, rebuilt = (obs["imagery"] for obs in policy.observations)
    np.testing.assert_array_equal(fresh["colour"], rebuilt["colour"])
    with np.load(entry) as repaired:  # the entry was written again, whole
        np.testing.assert_array_equal(repaired["height"], fresh["height"])


def test_an_unwritable_cache_is_an_error_not_a_failure(tmp_path):
    blocker = tmp_path / "cache"
    blocker.write_text("a file where the cache folder should be")
    policy = FixedPolicy(input_kind="imagery")
    with Evaluator(oracle_imagery_spec(blocker)) as evaluator:
        result = evaluator.run_episode(policy, 1)
    assert result.outcome == "error" and result.failure is None
    assert result.error.startswith("observation raised NotADirectoryError")
    assert policy.observations == []  # the policy never acted on it


def test_the_cache_key_carries_the_world_fingerprint(monkeypatch):
    spec = oracle_imagery_spec("unused")
    before = spec.imagery_key()
    monkeypatch.setattr(rollout, "world_fingerprint", lambda: "another-world")
    assert spec.imagery_key() != before


def test_progress_bars_leave_no_carriage_returns_in_logs(capsys):
    """Where stderr is a file or a pipe (CI logs, nohup), no bar frames are written."""
    with Evaluator(EvaluationSpec(task="block-insertion", imagery="oracle")) as evaluator:
        evaluator.run(FixedPolicy(), [1], progress=True)
    assert "\r" not in capsys.readouterr().err


def test_imagery_options_test_a_policy_on_an_imagery_candidate(tmp_path):
    """`evaluate-checkpoints --imagery-option`: the episode's NeRF imagery is fitted with the
    candidate's settings over the training data's, cached under a key of its own, and the record
    names them; on oracle views the options are refused."""
    datamodule = RavensDataModule(
        "block-insertion",
        pixel_size=0.0125,
        nerf_views=6,
        nerf_image_size=(60, 80),
        imagery_config={"iterations": 30, "sparsity_weight": 0.003},
        data_dir=str(tmp_path / "data"),
    )
    records = {}
    for name, options in (("training", None), ("candidate", {"iterations": 20})):
        policy = FixedPolicy(input_kind="imagery")
        records[name] = evaluate_policy(
            policy,
            datamodule,
            [1],
            split="test",
            imagery_options=options,
            cache_dir=str(tmp_path / "cache"),
            workers=1,
            progress=False,
        )
        records[name]["views"] = policy.observations[0]["imagery"]
    spec = EvaluationSpec.from_datamodule(
        datamodule, split="test", imagery_options={"iterations": 20}
    )
    assert spec.imagery_config().iterations == 20
    assert spec.imagery_config().sparsity_weight == 0.003  # the training's other settings stay
    assert len(list((tmp_path / "cache").rglob("*.npz"))) == 2  # two keys, two fits
    assert not np.array_equal(
        records["training"]["views"]["colour"], records["candidate"]["views"]["colour"]
    )
    assert "imagery_options" not in records["training"]
    assert records["candidate"]["imagery_options"] == {"iterations": 20}
    with pytest.raises(ValueError, match="set the NeRF imagery's fit; these views are oracle"):
        EvaluationSpec.from_datamodule(
            datamodule, split="test", imagery="oracle", imagery_options={"iterations": 20}
        )
