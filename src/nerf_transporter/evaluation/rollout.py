"""One closed-loop test episode for any method: reset with the seed, capture, build the method's
observation, `act`, execute the pick-and-place, judge (docs/conventions.md, "Evaluation protocol").

Each `Evaluator` owns its environments, and every environment its own PyBullet client, so an
evaluation never disturbs the simulator of data generation or of another evaluation. An episode is a
function of its seed, so `Evaluator.run(..., workers=N)` can share the episodes out among N worker
processes, each with its own `Evaluator` and copy of the policy (`evaluation.workers`), with the
results of a serial run.

An episode ends in one of three outcomes. `success`: the task was achieved (the anchor's reward:
what the table reports). `failure`: the robot acted and the task was not achieved (the object ended
off its target pose, a pose was unreachable, or the simulator faulted during the robot's motion),
with the reason. `error`: something that is not the robot's doing went wrong (imagery cache I/O,
the imagery fit, resetting the simulator, the policy raising, out of memory); an erred episode says
nothing about the policy, so success rates are computed over the episodes that ran, and errors are
reported on their own. The environment that raised is rebuilt for the next episode and the run
goes on.

Beside `success`, an episode that ran records `strict_success`: the project's stricter 6-DoF check
(`strict_errors` holds its errors; a simulator fault during the motion fails it too). An erred
episode has none (None), nor has a record written before it was recorded.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import torch

from nerf_transporter.console import progress_bar
from nerf_transporter.data.labels import mira_labels
from nerf_transporter.data.observation import (
    INPUT_KINDS,
    SceneConfig,
    SceneSpec,
    imagery_observation,
    imagery_observations,
    observation,
)
from nerf_transporter.evaluation.cache import ImageryCache, config_hash
from nerf_transporter.evaluation.video import EpisodeVideo, plan_panel
from nerf_transporter.evaluation.view_search import true_action, view_search_record
from nerf_transporter.evaluation.workers import EpisodeWorkers, RunnerRecipe, policy_recipe
from nerf_transporter.parallel import available_cores
from nerf_transporter.sim.fingerprint import world_fingerprint
from nerf_transporter.sim.tasks import POSE_ERROR_KEYS, pose_error_text

if TYPE_CHECKING:
    from nerf_transporter.imagery import ImageryConfig

log = logging.getLogger(__name__)

NOT_ACHIEVED = "task not achieved"
DEFAULT_CACHE_DIR = "data/imagery-cache"


class Policy(Protocol):
    """What evaluation needs from a method (every LightningModule of `nerf_transporter.methods`)."""

    input_kind: str
    training: bool

    def act(self, observation: dict) -> dict: ...

    def train(self, mode: bool = True) -> Any: ...


@dataclass(frozen=True, init=False)
class EvaluationSpec(SceneConfig):
    """Where and how episodes are evaluated: the scene (`data.observation.SceneSpec`; its fields
    read through, `spec.task`) and the imagery cache (`cache_dir=None` disables it).

    The scene's `imagery` says how the views of imagery methods are built: "nerf" fits a radiance
    field to the live RGB capture (the protocol), "oracle" renders the simulator's ground truth
    (upper bound); its imagery config must be the one the training data was built with, and its
    `pixel_size` sets the size of every image the methods see (imagery views and fused heightmaps).
    """

    scene: SceneSpec
    cache_dir: str | None = DEFAULT_CACHE_DIR

    def __init__(
        self,
        task: str | None = None,
        *,
        scene: SceneSpec | None = None,
        imagery_config: ImageryConfig | dict[str, Any] | None = None,
        cache_dir: str | None = DEFAULT_CACHE_DIR,
        **fields: Any,
    ) -> None:
        """`EvaluationSpec(scene=..., cache_dir=...)`, or with the fields of the scene (`task`,
        `setting`, `imagery`, `pixel_size`, `nerf_views`, `nerf_image_size`) and `imagery_config`
        (an `ImageryConfig` or its fields as a dict) for its imagery options."""
        if scene is None:
            if imagery_config is not None and not isinstance(imagery_config, dict):
                imagery_config = dataclasses.asdict(imagery_config)
            scene = SceneSpec(task, imagery_options=imagery_config or {}, **fields)
        elif task is not None or imagery_config is not None or fields:
            raise TypeError("EvaluationSpec takes a scene or the fields of one, not both")
        object.__setattr__(self, "scene", scene)
        object.__setattr__(self, "cache_dir", cache_dir)

    @classmethod
    def from_datamodule(
        cls,
        datamodule: Any,
        *,
        split: str = "validation",
        setting: str | None = None,
        imagery: str | None = None,
        imagery_options: dict[str, Any] | None = None,
        cache_dir: str | None = DEFAULT_CACHE_DIR,
    ) -> EvaluationSpec:
        """The spec matching the training data of a `RavensDataModule` (the scene of its
        generation config).

        `setting` defaults to the DataModule's `test_setting` for the test split (where it has
        one) and to its `setting` otherwise; `imagery` defaults to the training imagery.
        `imagery_options` (`ImageryConfig` fields) replace those of the training imagery's fit, to
        test a policy on another NeRF imagery (an imagery candidate); ValueError where the views
        are not `nerf` imagery.
        """
        if datamodule is None or not hasattr(datamodule, "generation_config"):
            raise ValueError(
                "closed-loop evaluation reads task, setting, cameras and imagery config from the "
                "RavensDataModule; configure one under `data:`"
            )
        scene = datamodule.generation_config(split, imagery=imagery).scene
        if setting is None and split == "test":
            setting = getattr(datamodule, "test_setting", None)
        if imagery_options and scene.imagery != "nerf":
            raise ValueError(
                f"imagery options ({', '.join(sorted(imagery_options))}) set the NeRF imagery's "
                f"fit; these views are {scene.imagery} imagery (ask for nerf imagery: "
                "`--imagery nerf`)"
            )
        scene = dataclasses.replace(
            scene,
            setting=setting or scene.setting,
            imagery_options={**scene.imagery_options, **(imagery_options or {})},
        )
        return cls(scene=scene, cache_dir=cache_dir)

    def imagery_key(self) -> str:
        """Hash of everything the imagery of a seed depends on besides task, setting and seed
        (the world fingerprint included: a changed world never reuses old imagery)."""
        description: dict[str, Any] = {
            "world": world_fingerprint(),
            "imagery": self.imagery,
            "views": self.grid,
            "pixel_size": self.pixel_size,
        }
        if self.imagery == "nerf":
            description |= {
                "config": self.scene.imagery_description(),
                "nerf_views": self.nerf_views,
                "nerf_image_size": list(self.nerf_image_size),
            }
        return config_hash(description)


@dataclass
class EpisodeResult:
    """Outcome of one episode. `failure`: why the robot did not achieve the task; `error`: what
    went wrong that was not the robot's doing (the episode then did not count); `pose_error`: how
    far the object ended from its target (the task's errors: position in metres, tilt and yaw in
    radians); `strict_success`: the project's stricter 6-DoF check (None where the episode erred or
    the environment did not judge it, as in records written before it was recorded), with its
    errors in `strict_errors`; `video`: the episode's mp4, if recorded; `view_search`: for a method
    that reports its view search (`mira`), where it placed against the true view
    (`evaluation.view_search`); `frames`: top-down colour before and after the action, if
    recorded."""

    seed: int
    success: bool
    failure: str | None
    error: str | None = None
    action: dict[str, list[float]] | None = None
    timings: dict[str, float] = field(default_factory=dict)
    imagery_cached: bool | None = None
    pose_error: dict[str, float] = field(default_factory=dict)
    strict_success: bool | None = None
    strict_errors: dict[str, float] = field(default_factory=dict)
    video: str | None = None
    view_search: dict[str, Any] | None = None
    frames: np.ndarray | None = None

    @property
    def outcome(self) -> str:
        """ "success", "failure" or "error" (see the module docstring)."""
        if self.error is not None:
            return "error"
        return "success" if self.success else "failure"

    def to_json(self) -> dict:
        record = dataclasses.asdict(self)
        record.pop("frames")
        return {"outcome": self.outcome} | record

    @classmethod
    def erred(cls, seed: int, error: str) -> EpisodeResult:
        """An episode that did not finish, for a reason not the robot's doing (`error`)."""
        return cls(seed=seed, success=False, failure=None, error=error)

    @classmethod
    def from_json(cls, record: dict) -> EpisodeResult:
        """The result back from its `to_json` record (without frames)."""
        return cls(**{key: value for key, value in record.items() if key != "outcome"})

    def outcome_text(self) -> str:
        """ "success", or why not (`failure_text`): the caption of strips and videos."""
        return "success" if self.success else str(self.failure_text())

    def failure_text(self) -> str | None:
        """Why the episode did not succeed: the error, or the failure reason with the pose errors
        where the task was simply not achieved."""
        if self.error is not None:
            return f"error: {self.error}"
        if self.failure == NOT_ACHIEVED and self.pose_error:
            return pose_error_text(self.pose_error)
        return self.failure


def strict_outcome(info: dict) -> bool | None:
    """The strict 6-DoF check of a step's info (`strict_success`), None where it has none."""
    strict = info.get("strict_success")
    return None if strict is None else bool(strict)


def _action_record(action: dict) -> dict[str, list[float]]:
    """{"pick": [x, y, z, qx, qy, qz, qw], "place": [...]} from an action of numpy poses."""
    record = {}
    for name in ("pick", "place"):
        xyz, quat = action[name]
        record[name] = [float(v) for v in np.concatenate([np.ravel(xyz), np.ravel(quat)])]
    return record


def policy_action(method: Policy, observation: dict) -> tuple[dict, Any]:
    """(`method.act(observation)`, its search or None) in eval mode without gradients; the
    training mode is restored. A method with `act_with_search` (`mira`) reports its search."""
    was_training = method.training
    method.train(False)
    try:
        with torch.no_grad():
            if hasattr(method, "act_with_search"):
                return method.act_with_search(observation)
            return method.act(observation), None
    finally:
        method.train(was_training)


EnvFactory = Callable[..., Any]


def _default_env_factory(task: str, setting: str, **options: Any) -> Any:
    from nerf_transporter.sim import make_env

    return make_env(task, setting, **options)


class Evaluator:
    """Runs episodes of one task/setting; environments (one per rig set) are built once and reused."""

    def __init__(
        self, spec: EvaluationSpec, env_factory: EnvFactory = _default_env_factory
    ) -> None:
        self.spec = spec
        self.env_factory = env_factory
        self.cache = ImageryCache(spec.cache_dir) if spec.cache_dir is not None else None
        self._envs: dict[tuple[str, ...], Any] = {}
        self._workers: EpisodeWorkers | None = None  # those of the last parallel run

    # -- environments -------------------------------------------------------------------------

    def _env(self, rigs: tuple[str, ...]) -> Any:
        if rigs not in self._envs:
            self._envs[rigs] = self.env_factory(
                self.spec.task,
                self.spec.setting,
                rigs=rigs,
                nerf_views=self.spec.nerf_views,
                nerf_image_size=self.spec.nerf_image_size,
                render_mode="rgb_array",  # side-camera frames for videos, when recorded
            )
        return self._envs[rigs]

    def _discard_env(self, rigs: tuple[str, ...]) -> None:
        env = self._envs.pop(rigs, None)
        if env is None:
            return
        try:
            env.close()
        except Exception:  # a broken client may fail to close; it is dropped either way
            log.warning("closing a failed environment raised", exc_info=True)

    def close(self) -> None:
        """Close the environments and stop the worker processes."""
        for rigs in list(self._envs):
            self._discard_env(rigs)
        if self._workers is not None:
            self._workers.close()
            self._workers = None

    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- observations -------------------------------------------------------------------------

    def _rigs(self, input_kind: str, cached: bool) -> tuple[str, ...]:
        if input_kind == "heightmap":
            return ("state", "rgbd")
        if input_kind == "imagery" and self.spec.imagery == "nerf" and not cached:
            return ("state", "nerf")
        return ("state",)

    def _load_imagery(self, seed: int) -> dict[str, np.ndarray] | None:
        if self.cache is None:
            return None
        return self.cache.load(self.spec.task, self.spec.setting, seed, self.spec.imagery_key())

    def _build_imagery(self, env: Any, obs: dict, seed: int) -> dict[str, np.ndarray]:
        """The imagery of the scene `env` was just reset to, built and saved to the cache."""
        imagery = imagery_observation(self.spec.scene, env, obs)
        if self.cache is not None:
            self.cache.save(
                self.spec.task, self.spec.setting, seed, self.spec.imagery_key(), imagery
            )
        return imagery

    def _observation(
        self, input_kind: str, env: Any, obs: dict, seed: int, imagery: dict | None
    ) -> dict:
        """The method's observation (`data.observation`); imagery built here goes to the cache."""
        if input_kind == "imagery" and imagery is None:
            imagery = self._build_imagery(env, obs, seed)
        return observation(input_kind, self.spec.scene, env, obs, imagery)

    def cache_imagery(self, seed: int, renderings: Sequence[dict[str, Any]] = ()) -> int:
        """Build the imagery of `seed`'s scene into the cache, as an imagery method's episode
        would before it acts, so that episodes run later only read it; with `renderings`, also
        that imagery rendered with each of these rendering options (`SceneSpec.rendered_with`,
        e.g. `{"depth": "median"}`) from the same fit, each cached under its own key as an
        evaluation with those imagery options reads it. The number of entries built (0 where all
        were cached). The global torch random state is restored afterwards."""
        if self.cache is None:
            raise ValueError("cache_imagery needs an imagery cache (the spec's cache_dir is None)")
        scenes = [self.spec.scene] + [self.spec.scene.rendered_with(r) for r in renderings]
        specs = {
            spec.imagery_key(): spec
            for spec in (dataclasses.replace(self.spec, scene=scene) for scene in scenes)
        }
        missing = {
            key: spec
            for key, spec in specs.items()
            if self.cache.load(spec.task, spec.setting, seed, key) is None
        }
        if not missing:
            return 0
        with torch.random.fork_rng():
            env = self._env(self._rigs("imagery", cached=False))
            obs, _ = env.reset(seed=seed)
            built = imagery_observations([spec.scene for spec in missing.values()], env, obs)
        for (key, spec), imagery in zip(missing.items(), built, strict=True):
            self.cache.save(spec.task, spec.setting, seed, key, imagery)
        return len(missing)

    # -- episodes -----------------------------------------------------------------------------

    def run_episode(
        self,
        method: Policy,
        seed: int,
        record_frames: bool = False,
        video_dir: str | os.PathLike | None = None,
    ) -> EpisodeResult:
        """Reset with `seed`, observe, act, execute, judge; never raises for a failing episode.
        With `video_dir`, the episode is also recorded there as an mp4 (`evaluation.video`).

        The global torch random state is restored afterwards (imagery fitting seeds it), so
        evaluating during training does not change the training run.
        """
        with torch.random.fork_rng():
            return self._episode(method, seed, record_frames, video_dir)

    def _episode(
        self, method: Policy, seed: int, record_frames: bool, video_dir: str | os.PathLike | None
    ) -> EpisodeResult:
        input_kind = getattr(method, "input_kind", None)
        if input_kind not in INPUT_KINDS:
            raise ValueError(
                f"{type(method).__name__}.input_kind is {input_kind!r}; "
                f"expected one of {', '.join(INPUT_KINDS)}"
            )
        timings: dict[str, float] = {}
        start = time.perf_counter()
        stage, rigs, cached, frames, action_record = "imagery cache", (), None, [], None
        video, info, strict_success, view_search = None, {}, None, None
        try:
            imagery = self._load_imagery(seed) if input_kind == "imagery" else None
            cached = imagery is not None if input_kind == "imagery" else None
            rigs = self._rigs(input_kind, bool(cached))
            stage = "reset"
            env = self._env(rigs)
            obs, _ = env.reset(seed=seed)
            timings["reset_s"] = time.perf_counter() - start
            if record_frames or video_dir:
                frames.append(env.render_orthographic(0.0, 0.0)[0])
            if video_dir:
                video = self._start_video(Path(video_dir), method, seed, env)
            stage = "observation"
            mark = time.perf_counter()
            observation = self._observation(input_kind, env, obs, seed, imagery)
            timings["observation_s"] = time.perf_counter() - mark
            stage = "act"
            mark = time.perf_counter()
            action, search = policy_action(method, observation)
            action_record = _action_record(action)
            timings["act_s"] = time.perf_counter() - mark
            if search is not None:  # before the step moves the object
                view_search = self._view_search(env, observation, action, search, method, seed)
            stage = "step"
            mark = time.perf_counter()
            if video is not None:
                video.begin(plan_panel(frames[0], action, self._chosen_view(observation, action)))
                env.frame_callback = video.add
            try:
                _, _, _, _, info = env.step(action)
            finally:
                env.frame_callback = None
            timings["step_s"] = time.perf_counter() - mark
            if record_frames:
                frames.append(env.render_orthographic(0.0, 0.0)[0])
            success = bool(info["success"])
            strict_success = strict_outcome(info)
            failure, error = None if success else (info.get("failure") or NOT_ACHIEVED), None
        except Exception as exception:
            if stage in ("reset", "observation", "step"):
                self._discard_env(rigs)
            text = f"{stage} raised {type(exception).__name__}: {exception}"
            robot_fault = stage == "step" and not isinstance(exception, MemoryError)
            log.warning(
                "episode with seed %d %s during %s",
                seed,
                "failed" if robot_fault else "erred (not counted)",
                stage,
                exc_info=True,
            )
            success, strict_success = False, False if robot_fault else None
            failure = f"simulator fault during the robot's motion ({text})" if robot_fault else None
            error = None if robot_fault else text
        timings["total_s"] = time.perf_counter() - start
        result = EpisodeResult(
            seed=seed,
            success=success,
            failure=failure,
            error=error,
            action=action_record,
            timings=timings,
            imagery_cached=cached,
            pose_error={k: float(info[k]) for k in POSE_ERROR_KEYS if info.get(k) is not None},
            strict_success=strict_success,
            strict_errors={
                key: float(value)
                for key, value in (info.get("strict_errors") or {}).items()
                if value is not None
            },
            view_search=view_search,
            frames=np.stack(frames) if record_frames and len(frames) == 2 else None,
        )
        if video is not None:
            written = video.close(result.outcome_text(), result.to_json())
            result.video = None if written is None else str(written)
        return result

    def _view_search(
        self, env: Any, observation: dict, action: dict, search: Any, method: Policy, seed: int
    ) -> dict[str, Any] | None:
        """The episode's `view_search` record; None (with a warning) where it cannot be made,
        which leaves the episode itself as it is."""
        try:
            return view_search_record(
                search,
                true_action(env.task, env, action["pick"]),
                observation["imagery"]["views"],
                self.spec.pixel_size,
                method.n_rotations,
            )
        except Exception:
            log.warning("episode with seed %d: no view-search record", seed, exc_info=True)
            return None

    # -- videos -------------------------------------------------------------------------------

    def _start_video(self, folder: Path, method: Policy, seed: int, env: Any) -> EpisodeVideo:
        """A video of this episode in `folder`, opening on the scene after reset."""
        name = str(getattr(method, "name", type(method).__name__))
        task, setting = self.spec.task, self.spec.setting
        return EpisodeVideo(
            folder / f"{task}-{setting}-seed{seed}-{name}.mp4",
            [f"{task} ({setting}), seed {seed}", f"method: {name}"],
            env.render(),
        )

    def _chosen_view(
        self, observation: dict, action: dict
    ) -> tuple[np.ndarray, tuple[float, float], str] | None:
        """For an imagery method, the grid view nearest to the place tilt (the view `act` chose
        the place in), with the place pixel in it and a title; None for the other methods."""
        if "imagery" not in observation:
            return None
        imagery = observation["imagery"]
        labels = mira_labels(action, np.asarray(imagery["views"]), self.spec.pixel_size)
        roll, pitch = np.degrees(np.asarray(imagery["views"])[labels.place_view])
        title = f"chosen view {labels.place_view}: roll {roll:.0f}, pitch {pitch:.0f} deg"
        return imagery["colour"][labels.place_view], tuple(labels.place_pixel), title

    def run(
        self,
        method: Policy,
        seeds: Iterable[int],
        progress: bool = False,
        desc: str = "evaluation",
        record_frames: int = 0,
        workers: int = 1,
        threads: int | None = None,
        video_dir: str | os.PathLike | None = None,
        video_episodes: int | None = None,
        on_result: Callable[[EpisodeResult], None] | None = None,
    ) -> list[EpisodeResult]:
        """Episodes for `seeds`, results in seed order, the first `record_frames` with frames; an
        optional progress bar shows the successes (and errors) so far. With `video_dir`, the first
        `video_episodes` (default: all) are recorded there as mp4s. `on_result` is called with each
        result as its episode ends, in this process (an `evaluation.journal.EpisodeJournal`
        keeps them there).

        With `workers` > 1 (and more than one seed) the episodes run in that many worker processes
        (`evaluation.workers`), each with `threads` torch threads (default: the available cores
        shared among them), with the same results as in this process. The worker processes are
        kept for the next run with as many workers, until `close`."""
        seeds = [int(seed) for seed in seeds]
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        workers = min(workers, len(seeds)) or 1
        successes, errors = 0, 0
        # leave=False: a terminal's bar goes when done, inside Lightning's own bar
        with progress_bar(len(seeds), desc, enabled=progress, leave=False) as bar:

            def count(result: EpisodeResult) -> None:
                nonlocal successes, errors
                successes += result.success
                errors += result.error is not None
                bar.set_postfix(successes=successes, **({"errors": errors} if errors else {}))
                bar.update(1)
                if on_result is not None:
                    on_result(result)

            videos = len(seeds) if video_episodes is None else video_episodes
            episodes = [
                (
                    seed,
                    {
                        "record_frames": index < record_frames,
                        "video_dir": str(video_dir) if video_dir and index < videos else None,
                    },
                )
                for index, seed in enumerate(seeds)
            ]
            if workers == 1:
                results = []
                for seed, options in episodes:
                    results.append(self.run_episode(method, seed, **options))
                    count(results[-1])
                return results
            return self._worker_processes(workers, threads).run(
                RunnerRecipe(Evaluator, (self.spec, self.env_factory)),
                policy_recipe(method),
                episodes,
                EpisodeResult.erred,
                count,
            )

    def _worker_processes(self, count: int, threads: int | None) -> EpisodeWorkers:
        threads = max(1, available_cores() // count) if threads is None else threads
        workers = self._workers
        if workers is None or (workers.count, workers.threads) != (count, threads):
            if workers is not None:
                workers.close()
            self._workers = EpisodeWorkers(count, threads)
        return self._workers


class Evaluators:
    """One open `Evaluator` at a time, kept while the spec stays the same: policies evaluated one
    after another (the checkpoints of a run) share its environments and worker processes."""

    def __init__(self) -> None:
        self._evaluator: Evaluator | None = None

    def get(self, spec: EvaluationSpec) -> Evaluator:
        """The open Evaluator of `spec`; one of another spec is closed first."""
        if self._evaluator is None or self._evaluator.spec != spec:
            self.close()
            self._evaluator = Evaluator(spec)
        return self._evaluator

    def close(self) -> None:
        if self._evaluator is not None:
            self._evaluator.close()
            self._evaluator = None

    def __enter__(self) -> Evaluators:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
