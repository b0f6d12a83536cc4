"""`nerf-transporter generate`: oracle demonstrations -> captures -> imagery -> episodes on disk.

For each seed of the split (splits.split_seed), in order: reset the simulator with the seed (the
observation of reset is the pre-pick capture), ask the task's oracle for the action, render the
ground-truth orthographic views it needs, execute the action; a failed rollout is recorded in
`failed/` and the next seed of the split is tried. A successful episode gets its imagery (the
simulator's ground truth with `--imagery oracle`, a radiance field fitted to the RGB views with
`--imagery nerf`) and is written atomically (episode.write_episode).

The dataset is "the first N successful seeds of the split": running again adds nothing, a larger
`--episodes` continues, an interrupted run resumes (a half-written episode is a temporary directory,
removed on the next run). `--shard i/n` takes the seed indices k with k % n == i and produces that
shard's share of the N episodes, so n machines together produce N.

dataset.json and every episode record the configuration and the world (sim.fingerprint) they were
made with: generating into a dataset of another configuration or world is refused, with the command
that starts it afresh (`--regenerate` deletes the dataset's episodes, failed seeds and dataset.json
first). Bad arguments are refused before anything is written.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import hashlib
import json
import math
import os
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.atomic import check_writable
from nerf_transporter.console import HelpFormatter, progress_bar
from nerf_transporter.data import episode as ep
from nerf_transporter.data.labels import heightmap_labels, mira_labels
from nerf_transporter.data.observation import (
    IMAGERY_KINDS,
    SceneConfig,
    SceneSpec,
    oracle_views,
    rounded,
    scene_imagery,
)
from nerf_transporter.parallel import exit_if_orphaned, process_pool
from nerf_transporter.sim import SETTINGS, TASKS, cameras, fingerprint
from nerf_transporter.sim.tasks import pose_error_text
from nerf_transporter.splits import SPLITS, split_seed


@dataclass(frozen=True, init=False)
class GenerationConfig(SceneConfig):
    """Everything an episode depends on besides its seed: the scene and the split (stored as the
    dataset's dataset.json). The scene's fields read through (`config.task`, `config.grid`)."""

    scene: SceneSpec
    split: str = "train"

    def __init__(
        self,
        task: str | None = None,
        setting: str = "normal",
        split: str = "train",
        *args: Any,
        scene: SceneSpec | None = None,
        **fields: Any,
    ) -> None:
        """`GenerationConfig(scene=..., split=...)`, or with the fields of the scene: `(task,
        setting, split, imagery, pixel_size, nerf_views, nerf_image_size, imagery_options)`."""
        if scene is None:
            scene = SceneSpec(task, setting, *args, **fields)
        elif task is not None or args or fields:
            raise TypeError("GenerationConfig takes a scene or the fields of one, not both")
        if split not in SPLITS:
            raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(SPLITS)}")
        object.__setattr__(self, "scene", scene)
        object.__setattr__(self, "split", split)

    def dataset_name(self) -> str:
        """<task>-<setting>-<split>, with -oracle and -px<size> for non-default imagery or pixels,
        and -imagery<hash> for NeRF imagery settings other than the reference imagery's (a hash
        of `SceneSpec.imagery_changes`: a candidate's data, or a changed default's, sits beside
        the reference's)."""
        name = f"{self.task}-{self.setting}-{self.split}"
        if self.imagery != "nerf":
            name += f"-{self.imagery}"
        if not math.isclose(self.pixel_size, g.PIXEL_SIZE):
            name += f"-px{self.pixel_size:g}"
        if changes := self.scene.imagery_changes():
            text = json.dumps(changes, sort_keys=True)
            name += f"-imagery{hashlib.sha256(text.encode()).hexdigest()[:8]}"
        return name

    def description(self) -> dict[str, Any]:
        """The content of dataset.json (and of each episode's record): what must match to append."""
        description: dict[str, Any] = {
            "format": ep.FORMAT_VERSION,
            "world": fingerprint.world(),
            "task": self.task,
            "setting": self.setting,
            "split": self.split,
            "pixel_size": self.pixel_size,
            "image_shape": list(g.image_shape(self.pixel_size)),
            "view_grid": {
                "views": len(self.grid),
                "roll_pitch_limit": float(np.abs(self.grid).max()),
            },
            "cameras": {
                "nerf": {"views": self.nerf_views, "image_size": list(self.nerf_image_size)},
                "rgbd": {"views": 3},
            },
            "imagery": {"kind": self.imagery},
        }
        if self.imagery == "nerf":
            description["imagery"]["config"] = self.scene.imagery_description()
        return description

    def command(
        self, episodes: int, data_dir: str | os.PathLike, *, regenerate: bool = False
    ) -> str:
        """The `nerf-transporter generate` command line that produces this dataset (afresh)."""
        words = [
            "nerf-transporter generate",
            f"--task {self.task}",
            f"--setting {self.setting}",
            f"--split {self.split}",
            f"--episodes {episodes}",
            f"--imagery {self.imagery}",
            f"--data-dir {data_dir}",
        ]
        if not math.isclose(self.pixel_size, g.PIXEL_SIZE):
            words.append(f"--pixel-size {self.pixel_size:g}")
        if self.nerf_views != 30:
            words.append(f"--nerf-views {self.nerf_views}")
        if self.nerf_image_size != cameras.IMAGE_SIZE:
            words.append(f"--nerf-image-size {self.nerf_image_size[0]}x{self.nerf_image_size[1]}")
        words += [
            f"--imagery-option {key}={value}" for key, value in sorted(self.imagery_options.items())
        ]
        if regenerate:
            words.append("--regenerate")
        return " ".join(words)


@dataclass(frozen=True)
class Outcome:
    index: int
    seed: int
    success: bool
    reason: str | None
    seconds: float


# ---------------------------------------------------------------------------------------------
# One episode
# ---------------------------------------------------------------------------------------------

_ENVS: dict[tuple, Any] = {}


def _env(config: GenerationConfig):
    """One simulator per process and config (building a world is much slower than resetting it)."""
    rigs = ("state", "rgbd") + (("nerf",) if config.nerf_views > 0 else ())
    key = (config.task, config.setting, rigs, config.nerf_views, config.nerf_image_size)
    if key not in _ENVS:
        from nerf_transporter.sim import make_env

        _ENVS[key] = make_env(
            config.task,
            config.setting,
            rigs=rigs,
            nerf_views=max(config.nerf_views, 1),
            nerf_image_size=config.nerf_image_size,
        )
    return _ENVS[key]


def _pose_json(pose: g.Pose) -> dict[str, list[float]]:
    return {"xyz": [float(v) for v in pose[0]], "quat_xyzw": [float(v) for v in pose[1]]}


def action_from_meta(meta: dict[str, Any]) -> dict[str, g.Pose]:
    """The oracle action stored in an episode's meta.json."""
    return {
        name: (np.array(pose["xyz"]), np.array(pose["quat_xyzw"]))
        for name, pose in meta["action"].items()
    }


def imagery_quality(
    colour: np.ndarray, height: np.ndarray, true_colour: np.ndarray, true_height: np.ndarray
) -> dict[str, float | None]:
    """Colour PSNR (dB) and mean absolute height error (mm, all pixels and object pixels)."""
    from nerf_transporter.imagery import height_mae_mm, psnr

    overall, on_objects = height_mae_mm(height, true_height)
    return {
        "psnr_db": psnr(colour, true_colour),
        "height_mae_mm": overall,
        "object_height_mae_mm": None if math.isnan(on_objects) else on_objects,
    }


def generate_episode(
    config: GenerationConfig, dataset_dir: str | os.PathLike, index: int
) -> Outcome:
    """Roll out the oracle on seed `split_seed(split, index)` and write the episode if it succeeds."""
    start = time.perf_counter()
    seed = split_seed(config.split, index)
    env = _env(config)
    obs, _ = env.reset(seed=seed)
    capture_s = time.perf_counter() - start
    action = env.task.oracle(env)
    grid = config.grid
    try:
        place_view = mira_labels(action, grid, config.pixel_size).place_view
        heightmap_labels(action, config.pixel_size)
    except ValueError as error:
        ep.record_failure(dataset_dir, seed, f"label outside the image: {error}")
        return Outcome(index, seed, False, "label outside the image", time.perf_counter() - start)

    pick_view = g.top_down_view_index(grid)
    truth_ids = range(len(grid)) if config.imagery == "oracle" else sorted({pick_view, place_view})
    render_start = time.perf_counter()
    truth = oracle_views(env, grid[list(truth_ids)], config.pixel_size)
    truth_s = time.perf_counter() - render_start

    rollout_start = time.perf_counter()
    _, _, _, _, info = env.step(action)
    rollout_s = time.perf_counter() - rollout_start
    if not info["success"]:
        reason = info.get("failure") or pose_error_text(info)
        ep.record_failure(dataset_dir, seed, reason)
        return Outcome(index, seed, False, reason, time.perf_counter() - start)

    imagery_start = time.perf_counter()
    quality = None
    if config.imagery == "oracle":
        colour, height = truth  # all views, seen before the robot moved
    else:
        colour, height = scene_imagery(config.scene, env, obs)
        quality = imagery_quality(colour[list(truth_ids)], height[list(truth_ids)], *truth)
    imagery_s = time.perf_counter() - imagery_start

    colour, height = rounded(colour, height)
    imagery_arrays = {
        "colour": colour,
        "height": height,
        "views": grid.astype(np.float32),
        "pick_view": np.int64(pick_view),
        "place_view": np.int64(place_view),
    }
    if config.imagery == "nerf":
        truth_colour, truth_height = rounded(*truth)
        imagery_arrays |= {
            "truth_view_ids": np.array(list(truth_ids), dtype=np.int64),
            "truth_colour": truth_colour,
            "truth_height": truth_height,
        }
    arrays = {
        "rgbd": {key: np.asarray(value) for key, value in obs["rgbd"].items()},
        "imagery": imagery_arrays,
    }
    if config.nerf_views > 0:
        arrays["nerf_views"] = {key: np.asarray(value) for key, value in obs["nerf"].items()}
    meta = {
        "task": config.task,
        "setting": config.setting,
        "split": config.split,
        "success": True,
        # the project's stricter 6-DoF check of the oracle's episode (None: the world has none)
        "strict_success": None
        if info.get("strict_success") is None
        else bool(info["strict_success"]),
        "action": {name: _pose_json(pose) for name, pose in action.items()},
        "state": [float(v) for v in obs["state"]],
        "imagery": {"kind": config.imagery, "quality": quality},
        ep.GENERATION_KEY: config.description(),
        "timings_s": {
            "capture": capture_s,
            "ground_truth_views": truth_s,
            "rollout": rollout_s,
            "imagery": imagery_s,
            "total": time.perf_counter() - start,
        },
    }
    exit_if_orphaned()
    ep.write_episode(dataset_dir, index, seed, meta, arrays)
    return Outcome(index, seed, True, None, time.perf_counter() - start)


# ---------------------------------------------------------------------------------------------
# A dataset
# ---------------------------------------------------------------------------------------------


def parse_shard(text: str) -> tuple[int, int]:
    """ "i/n" -> (i, n) with 0 <= i < n."""
    try:
        shard, count = (int(v) for v in text.split("/"))
    except ValueError as error:
        raise ValueError(f"--shard must look like i/n (e.g. 0/4), got {text!r}") from error
    if not 0 <= shard < count:
        raise ValueError(f"--shard {text}: need 0 <= i < n")
    return shard, count


def shard_target(episodes: int, shard: tuple[int, int]) -> int:
    """Episodes shard i of n produces so that all n shards together produce `episodes`."""
    index, count = shard
    return episodes // count + (1 if index < episodes % count else 0)


class _InlineExecutor(cf.Executor):
    """Runs each task at submission in this process (`--workers 1`)."""

    def submit(self, fn, /, *args, **kwargs):
        future: cf.Future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as error:  # noqa: BLE001 - handed to the caller through the future
            future.set_exception(error)
        return future


def _executor(workers: int) -> cf.Executor:
    return _InlineExecutor() if workers <= 1 else process_pool(workers)


def dataset_status(
    dataset_dir: str | os.PathLike, shard: tuple[int, int] = (0, 1)
) -> tuple[set[int], set[int]]:
    """(seed indices with an episode, seeds that failed) of a dataset, restricted to a shard."""
    done = {ref.index for ref in ep.list_episodes(dataset_dir) if ref.index % shard[1] == shard[0]}
    return done, set(ep.failed_seeds(dataset_dir))


def generate_dataset(
    config: GenerationConfig,
    episodes: int,
    data_dir: str | os.PathLike = "data",
    *,
    workers: int = 1,
    shard: tuple[int, int] = (0, 1),
    progress: bool = True,
    max_failures_in_a_row: int = 50,
    regenerate: bool = False,
) -> Path:
    """Make `<data_dir>/<dataset name>` hold `episodes` episodes (this shard's share of them).

    Data of another configuration or world is refused (ep.check_dataset_config); with `regenerate`
    the dataset's episodes, failed seeds and dataset.json are deleted first. Gives up with
    RuntimeError after `max_failures_in_a_row` failed rollouts in a row. Where episodes are to be
    written, a dataset folder that cannot be written is refused before the first rollout
    (`atomic.UnwritableError`)."""
    if episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {episodes}")
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    dataset_dir = Path(data_dir) / config.dataset_name()
    target = shard_target(episodes, shard)
    done, failed = dataset_status(dataset_dir, shard)
    if regenerate or len(done) < target:  # a complete dataset is only read
        check_writable("--data-dir", dataset_dir)
    if regenerate:
        ep.remove_dataset(dataset_dir)
        done, failed = dataset_status(dataset_dir, shard)
    ep.ensure_dataset_config(
        dataset_dir, config.description(), config.command(episodes, data_dir, regenerate=True)
    )
    ep.remove_stale_temp_dirs(dataset_dir)
    todo = _pending_indices(config.split, shard, done, failed)

    bar = progress_bar(
        target, config.dataset_name(), enabled=progress, initial=min(len(done), target)
    )
    failures, failures_in_a_row, seconds = 0, 0, []
    pending: dict[cf.Future, int] = {}
    with _executor(workers) as pool:
        while True:
            while len(done) + len(pending) < target and len(pending) < max(workers, 1):
                index = next(todo)
                pending[pool.submit(generate_episode, config, dataset_dir, index)] = index
            if not pending:
                break
            finished, _ = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
            for future in finished:
                pending.pop(future)
                outcome = future.result()
                seconds.append(outcome.seconds)
                failures += not outcome.success
                bar.set_postfix(failures=failures, s_per_episode=f"{np.mean(seconds):.1f}")
                if outcome.success:
                    done.add(outcome.index)
                    bar.update(1)
                    failures_in_a_row = 0
                else:
                    failures_in_a_row += 1
                    if failures_in_a_row >= max_failures_in_a_row:
                        raise RuntimeError(
                            f"{config.dataset_name()}: {failures_in_a_row} oracle rollouts failed in a "
                            f"row (last: seed {outcome.seed}, {outcome.reason}); is the task's oracle broken?"
                        )
    bar.close()
    return dataset_dir


def _pending_indices(
    split: str, shard: tuple[int, int], done: set[int], failed: set[int]
) -> Iterator[int]:
    """Seed indices of the shard, in order, that have neither an episode nor a recorded failure."""
    index = shard[0]
    while True:
        try:
            seed = split_seed(split, index)
        except ValueError as error:
            raise RuntimeError(f"split {split!r} has no seeds left: {error}") from error
        if index not in done and seed not in failed:
            yield index
        index += shard[1]


# ---------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------


def imagery_option(text: str) -> tuple[str, Any]:
    from nerf_transporter.imagery import ImageryConfig

    key, sep, value = text.partition("=")
    fields = {f.name: f for f in dataclasses.fields(ImageryConfig)}
    if not sep or key not in fields:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE with KEY one of: {', '.join(fields)}")
    default = getattr(ImageryConfig(), key)
    if isinstance(default, bool):
        return key, value.lower() in ("1", "true", "yes")
    if isinstance(default, tuple):
        return key, tuple(type(default[0])(v) for v in value.split(","))
    return key, type(default)(value) if default is not None else value


def add_imagery_option_argument(parser: argparse.ArgumentParser, help: str) -> None:
    """`--imagery-option KEY=VALUE` (repeatable; `imagery_option`), collected in a list."""
    parser.add_argument(
        "--imagery-option",
        type=imagery_option,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help=help,
    )


def _image_size(text: str) -> tuple[int, int]:
    rows, _, cols = text.partition("x")
    return int(rows), int(cols)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter generate",
        description="Generate oracle demonstrations with their captures and imagery.",
        formatter_class=HelpFormatter,
    )
    # validated by GenerationConfig, whose one-line errors name the valid values
    parser.add_argument("--task", required=True, help=f"one of {', '.join(sorted(TASKS))}")
    parser.add_argument("--setting", default="normal", help=f"one of {', '.join(SETTINGS)}")
    parser.add_argument("--split", default="train", choices=SPLITS, help="seed range")
    parser.add_argument("--episodes", type=int, required=True, help="successful episodes wanted")
    parser.add_argument(
        "--imagery", default="nerf", choices=IMAGERY_KINDS, help="NeRF fit or simulator views"
    )
    parser.add_argument("--data-dir", default="data", help="datasets go in <data-dir>/<name>")
    parser.add_argument("--workers", type=int, default=1, help="processes")
    parser.add_argument(
        "--shard", default="0/1", help="i/n: this machine takes seed indices k %% n == i"
    )
    parser.add_argument("--pixel-size", type=float, default=g.PIXEL_SIZE, help="of the imagery (m)")
    parser.add_argument(
        "--nerf-views", type=int, default=30, help="RGB views stored (0: none, oracle only)"
    )
    parser.add_argument(
        "--nerf-image-size", type=_image_size, default=cameras.IMAGE_SIZE, help="ROWSxCOLS"
    )
    add_imagery_option_argument(parser, "an ImageryConfig field for --imagery nerf (repeatable)")
    parser.add_argument(
        "--regenerate",
        action="store_true",
        help="first delete the dataset's episodes, failed seeds and dataset.json (e.g. after the "
        "world changed); with --shard, pass it to one shard only, before the others start",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config = GenerationConfig(
            task=args.task,
            setting=args.setting,
            split=args.split,
            imagery=args.imagery,
            pixel_size=args.pixel_size,
            nerf_views=args.nerf_views,
            nerf_image_size=args.nerf_image_size,
            imagery_options=dict(args.imagery_option),
        )
        shard = parse_shard(args.shard)
        dataset_dir = generate_dataset(
            config,
            args.episodes,
            args.data_dir,
            workers=args.workers,
            shard=shard,
            progress=not args.no_progress,
            regenerate=args.regenerate,
        )
    except (ValueError, RuntimeError, ep.DatasetConfigMismatchError) as error:
        print(f"nerf-transporter generate: {error}", file=sys.stderr)
        return 2
    done, failed = dataset_status(dataset_dir)
    print(f"{dataset_dir}: {len(done)} episodes, {len(failed)} failed seeds")
    return 0
