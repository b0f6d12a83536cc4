"""Episodes in worker processes (`Evaluator.run(..., workers=N)`).

Each worker process builds its own episode runner from a `RunnerRecipe` (an `Evaluator` of
`evaluation.rollout`: its own environments and PyBullet clients, the same `EvaluationSpec`) and its
own copy of the policy, rebuilt from a `PolicyRecipe`: a picklable factory (a method's class with
its hyper-parameters) and the parent's weights. An episode is a function of its seed
(`Evaluator.run_episode`), so the results are those of a serial run. This module knows the runner
only by what it does (`EpisodeRunner`), so that the rollout, which starts the workers, imports it
and not the other way round.

Every worker is a pool of one process running one episode at a time: a worker process that dies
(killed, out of memory) takes only its own episode with it. That episode becomes an `error`
outcome, the worker is started afresh, and the remaining seeds run on.
"""

from __future__ import annotations

import concurrent.futures as cf
import functools
import inspect
import io
import logging
import pickle
from collections import deque
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Protocol

import torch

from nerf_transporter.parallel import exit_if_orphaned, process_pool

log = logging.getLogger(__name__)

WORKER_DIED = (
    "the worker process running this episode died (killed, or out of memory?); "
    "the episode did not finish"
)


class EpisodeRunner(Protocol):
    """What a worker process runs its episodes with (`evaluation.rollout.Evaluator`)."""

    def run_episode(self, policy: Any, seed: int, **options: Any) -> Any: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class RunnerRecipe:
    """How a worker process builds its episode runner: `make(*arguments)`, both picklable. A worker
    keeps the runner (its environments) for the next round of an equal recipe."""

    make: Callable[..., EpisodeRunner]
    arguments: tuple[Any, ...]

    def build(self) -> EpisodeRunner:
        return self.make(*self.arguments)


@dataclass(frozen=True)
class PolicyRecipe:
    """How a worker process rebuilds a policy: `factory()`, the weights, eval mode, `device`."""

    factory: Callable[[], Any]
    state: bytes  # the state_dict, torch.save'd (tensors on the CPU)
    device: str

    def build(self) -> Any:
        policy = self.factory()
        state = torch.load(io.BytesIO(self.state), map_location="cpu", weights_only=True)
        policy.load_state_dict(state)
        return policy.to(self.device).eval()


def accepted_keywords(cls: type) -> set[str] | None:
    """The keyword arguments `cls(...)` takes, following a `**kwargs` that an `__init__` passes
    on to the next class of the chain (as the methods do); None when the chain takes any."""
    names: set[str] = set()
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = list(inspect.signature(vars(klass)["__init__"]).parameters.values())[1:]
        names |= {p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            return names
    return None


def policy_factory(policy: Any) -> Callable[[], Any]:
    """A picklable callable that builds an untrained copy of `policy`.

    A LightningModule is rebuilt from its class and its hyper-parameters (`save_hyperparameters`;
    the keys its `__init__` chain does not take, such as LightningCLI's `_class_path`, are left
    out). Any other policy provides `worker_factory()`."""
    if hasattr(policy, "worker_factory"):
        return policy.worker_factory()
    hparams = getattr(policy, "hparams", None)
    if hparams is None:
        raise TypeError(
            f"{type(policy).__name__} cannot be copied into evaluation worker processes: it is "
            "not a LightningModule with hyper-parameters and has no worker_factory(); "
            "evaluate it with workers=1"
        )
    cls = type(policy)
    accepted = accepted_keywords(cls)
    arguments = {k: v for k, v in hparams.items() if accepted is None or k in accepted}
    return functools.partial(cls, **arguments)


def policy_recipe(policy: Any) -> PolicyRecipe:
    """The recipe that rebuilds `policy` in a worker process; TypeError if it cannot be sent."""
    factory = policy_factory(policy)
    try:
        pickle.dumps(factory)
    except (pickle.PicklingError, TypeError, AttributeError) as error:
        raise TypeError(
            f"{type(policy).__name__} cannot be copied into evaluation worker processes, its "
            f"factory does not pickle ({error}); evaluate it with workers=1"
        ) from error
    buffer = io.BytesIO()
    torch.save({k: v.detach().cpu() for k, v in policy.state_dict().items()}, buffer)
    parameter = next(iter(policy.parameters()), None)
    device = str(parameter.device) if parameter is not None else "cpu"
    return PolicyRecipe(factory, buffer.getvalue(), device)


# -- in a worker process -----------------------------------------------------------------------

_WORKER: dict[str, Any] = {}  # this worker's runner, the recipe it was built from, the policy


def _prepare(runner: RunnerRecipe, recipe: PolicyRecipe) -> None:
    """Install this round's policy; keep the runner (its environments) built from an equal recipe."""
    if _WORKER.get("runner_recipe") != runner:
        if "runner" in _WORKER:
            _WORKER["runner"].close()
        _WORKER["runner"] = runner.build()
        _WORKER["runner_recipe"] = runner
    _WORKER["policy"] = recipe.build()


def _episode(seed: int, options: dict[str, Any]) -> Any:
    exit_if_orphaned()
    return _WORKER["runner"].run_episode(_WORKER["policy"], seed, **options)


# -- in the evaluating process -----------------------------------------------------------------


@dataclass
class _Worker:
    pool: cf.ProcessPoolExecutor
    prepared: cf.Future | None = None  # this round's _prepare


class EpisodeWorkers:
    """`count` worker processes with `threads` torch threads each; they are started on first use
    and kept across `run`s (their environments too) until `close`."""

    def __init__(self, count: int, threads: int) -> None:
        if count < 1 or threads < 1:
            raise ValueError(f"need count >= 1 and threads >= 1, got {count} and {threads}")
        self.count = count
        self.threads = threads
        self._workers: list[_Worker | None] = [None] * count

    def run(
        self,
        runner: RunnerRecipe,
        recipe: PolicyRecipe,
        episodes: list[tuple[int, dict[str, Any]]],
        erred: Callable[[int, str], Any],
        on_result: Callable[[Any], None] = lambda result: None,
    ) -> list[Any]:
        """Results of `episodes` ((seed, `run_episode` options) pairs) in their order; `on_result` is
        called as each one finishes. An episode whose worker process died ends as `erred(seed,
        WORKER_DIED)`. A policy that cannot be rebuilt in a worker raises."""
        for worker in self._workers:
            if worker is not None:
                worker.prepared = None
        prepare = (runner, recipe)
        results: list[Any] = [None] * len(episodes)
        queue = deque(enumerate(episodes))
        idle = list(range(self.count))
        running: dict[cf.Future, tuple[int, int]] = {}
        try:
            while queue or running:
                while queue and idle:
                    slot = idle.pop()
                    position, (seed, options) = queue.popleft()
                    running[self._submit(slot, prepare, seed, options)] = (slot, position)
                finished, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
                for future in finished:
                    slot, position = running.pop(future)
                    results[position] = self._result(slot, future, episodes[position][0], erred)
                    on_result(results[position])
                    idle.append(slot)
        except BaseException:
            self.close(wait=False)
            raise
        return results

    def _submit(self, slot: int, prepare: tuple, seed: int, options: dict) -> cf.Future:
        try:
            return self._submit_to(slot, prepare, seed, options)
        except BrokenProcessPool:  # the idle process died since its last episode: start afresh
            self._discard(slot)
            return self._submit_to(slot, prepare, seed, options)

    def _submit_to(self, slot: int, prepare: tuple, seed: int, options: dict) -> cf.Future:
        worker = self._workers[slot]
        if worker is None:
            worker = self._workers[slot] = _Worker(process_pool(1, self.threads))
        if worker.prepared is None:
            worker.prepared = worker.pool.submit(_prepare, *prepare)
        return worker.pool.submit(_episode, seed, options)

    def _result(
        self, slot: int, future: cf.Future, seed: int, erred: Callable[[int, str], Any]
    ) -> Any:
        error = self._workers[slot].prepared.exception()  # it ran before the episode
        if error is not None and not isinstance(error, BrokenProcessPool):
            raise RuntimeError(
                "an evaluation worker process could not rebuild the policy: "
                f"{type(error).__name__}: {error}"
            ) from error
        if error is None:
            try:
                return future.result()
            except BrokenProcessPool:
                pass  # the process died during the episode
        log.warning("episode with seed %d erred (not counted): %s", seed, WORKER_DIED)
        self._discard(slot)
        return erred(seed, WORKER_DIED)

    def _discard(self, slot: int) -> None:
        worker = self._workers[slot]
        self._workers[slot] = None
        if worker is not None:
            worker.pool.shutdown(wait=False, cancel_futures=True)

    def close(self, wait: bool = True) -> None:
        """Stop the worker processes; with `wait=False`, without waiting for running episodes
        (those processes end after their episode, or with this process)."""
        for slot, worker in enumerate(self._workers):
            if worker is not None:
                worker.pool.shutdown(wait=wait, cancel_futures=True)
            self._workers[slot] = None
