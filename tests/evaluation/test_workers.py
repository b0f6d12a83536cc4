"""Episodes in worker processes: the same results as in the evaluating process, a copy of the
policy's weights in every worker, and a worker that dies costs only its own episode."""

import functools
import os
import signal

import numpy as np
import pytest
import torch

from nerf_transporter.evaluation.rollout import EvaluationSpec, Evaluator
from nerf_transporter.evaluation.workers import WORKER_DIED, policy_recipe
from nerf_transporter.methods import GTStateMLP
from nerf_transporter.sim import make_env

UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])


class NudgePolicy(torch.nn.Module):
    """Picks the object where the state (or the highest imagery point) says, places it by its
    `offset` weights: actions that depend on the observation and on the weights."""

    def __init__(self, input_kind="state"):
        super().__init__()
        self.input_kind = input_kind
        self.offset = torch.nn.Parameter(torch.zeros(3))

    def worker_factory(self):
        return functools.partial(NudgePolicy, self.input_kind)

    def act(self, observation):
        if self.input_kind == "state":
            pick = np.asarray(observation["state"][:3], dtype=float)
        else:
            height = observation["imagery"]["height"][0]
            pick = np.array([0.5, 0.0, float(height.max())])
        place = pick + self.offset.detach().double().numpy()
        return {"pick": (pick, UPRIGHT), "place": (place, UPRIGHT)}


def records(results):
    return [{k: v for k, v in r.to_json().items() if k != "timings"} for r in results]


@pytest.mark.parametrize("input_kind", ["state", "imagery"])
def test_episodes_in_two_workers_are_those_of_a_serial_run(input_kind):
    spec = EvaluationSpec(
        task="block-insertion", imagery="oracle", pixel_size=0.025, cache_dir=None
    )
    policy = NudgePolicy(input_kind)
    with torch.no_grad():
        policy.offset.copy_(torch.tensor([0.0, 0.15, 0.01]))  # only the weights say so
    seeds = [4, 1, 3, 2]
    with Evaluator(spec) as evaluator:
        serial = evaluator.run(policy, seeds, record_frames=2)
        parallel = evaluator.run(policy, seeds, record_frames=2, workers=2)
    assert [r.seed for r in parallel] == seeds
    assert records(parallel) == records(serial)
    assert all(r.error is None and set(r.timings) >= {"act_s", "total_s"} for r in parallel)
    for one, other in zip(serial, parallel, strict=True):
        if one.frames is None:
            assert other.frames is None
        else:
            np.testing.assert_array_equal(one.frames, other.frames)
    assert [r.frames is not None for r in parallel] == [True, True, False, False]


class KillingEnvFactory:
    """make_env, except that outside the test process resetting to `seed` kills the process."""

    def __init__(self, seed):
        self.seed = seed
        self.test_process = os.getpid()

    def __call__(self, task, setting, **options):
        env = make_env(task, setting, **options)
        reset = env.reset

        def killing_reset(seed=None, **kwargs):
            if seed == self.seed and os.getpid() != self.test_process:
                os.kill(os.getpid(), signal.SIGKILL)
            return reset(seed=seed, **kwargs)

        env.reset = killing_reset
        return env


def test_a_worker_that_dies_errs_its_episode_and_the_others_run_on():
    spec = EvaluationSpec(task="block-insertion", imagery="oracle", cache_dir=None)
    policy = NudgePolicy()
    seeds = [1, 2, 3, 5]
    with Evaluator(spec, KillingEnvFactory(seed=2)) as evaluator:
        serial = evaluator.run(policy, seeds)
        parallel = evaluator.run(policy, seeds, workers=2)
    died = parallel[1]
    assert died.seed == 2 and died.outcome == "error" and died.error == WORKER_DIED
    assert records(parallel[:1] + parallel[2:]) == records(serial[:1] + serial[2:])


def test_a_method_travels_as_class_hyper_parameters_and_weights():
    method = GTStateMLP(state_dim=14, hidden=16, layers=2)
    method.hparams["_class_path"] = "nerf_transporter.methods.GTStateMLP"  # as LightningCLI does
    method.train()
    copy = policy_recipe(method).build()
    assert type(copy) is GTStateMLP and not copy.training
    assert copy.hparams == {k: v for k, v in method.hparams.items() if k != "_class_path"}
    for name, tensor in method.state_dict().items():
        torch.testing.assert_close(copy.state_dict()[name], tensor, rtol=0, atol=0)


def test_a_policy_that_cannot_be_rebuilt_in_a_worker_is_refused_clearly():
    class Local(torch.nn.Module):
        input_kind = "state"

        def worker_factory(self):
            return Local

    with pytest.raises(TypeError, match="Local cannot be copied into evaluation worker"):
        policy_recipe(Local())
    with pytest.raises(TypeError, match="evaluate it with workers=1"):
        policy_recipe(torch.nn.Linear(2, 2))
