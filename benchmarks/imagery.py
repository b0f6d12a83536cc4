"""Mental-imagery benchmark: fit time, view-grid render time and quality against the simulator.

    python benchmarks/imagery.py --task block-insertion --episodes 2 --json
    python benchmarks/imagery.py --dataset data/block-insertion-normal-train --episodes 4
    python benchmarks/imagery.py --task place-red-in-green --setting challenging --threads 1 \
        --rig mira30 --imagery-option image_downscale=1
    python benchmarks/imagery.py --task place-red-in-green --setting challenging --episodes 100 \
        --cached data/imagery-cache --imagery-option iterations=800

A candidate imagery is scored without a policy: `--imagery-option KEY=VALUE` sets any field of
the fit's settings (`ImageryConfig`, as `generate --imagery-option`), and `--rig` captures the
scenes with another NeRF rig (`RIGS`: the world's, MIRA's band of elevations, a low band), handed
to the environment, so the world's default rig and its fingerprint stay as they are.

With `--dataset` (no simulator needed: a GPU machine without PyBullet) the scenes are a NeRF
dataset's episodes: their stored 30 RGB views are fitted again with the dataset's own imagery
settings on this device, and the truth is the simulator's renders stored beside the imagery
(`truth_view_ids`, the pick and place views); the stored imagery, fitted where the dataset was made,
is scored against the same truth, so the two fits compare on identical inputs.

With `--cached` nothing is fitted or simulated: the NeRF imagery that the imagery cache already
holds for the test seeds (built by a test of the candidate, `evaluate-checkpoints --imagery-option`,
or by `cache-imagery`) is scored against the simulator's imagery cached beside it (`--imagery
oracle`), so a candidate is scored on the very scenes of its swap test, 100 of them in minutes.

Per scene: fit seconds, render seconds for the whole view grid, PSNR of the top-down view and the
mean over the grid, height MAE (mm) overall and on object pixels (top-down view), and with the
simulator the grid's height MAE and PSNR by view tilt (the view's axis from the vertical, bins of
`VIEW_TILT_BINS_DEG`: the 7 x 7 Normal grid reaches 41 deg, the 11 x 11 Challenging one 60), over
the workspace (the pixels whose true surface lies over it, those mira places at) and on object
pixels (those of them whose true surface stands over 5 mm above the table in the world), and
PSNR at the true colour's edges and off them (`colour_edges`: outlines, where a radiance field
blurs; `view_errors`), and the top-down view's object footprint against the simulator's (the
pixels over 5 mm it adds and misses, and their IoU: `footprint_errors`). The steepest views' image borders see past the workspace, where the simulator and
the NeRF's floor disagree by up to metres: the grid's all-pixel figure (height_mae_grid_mm) counts
them, the per-tilt ones do not. Times are wall seconds, and also process CPU seconds (fit_cpu_s,
render_cpu_s, and their sums fit_render_s, fit_render_cpu_s), steadier than wall time on a shared
machine (meaningless for GPU work, which they miss). The first line names the device (GPU name, or
CPU model and torch threads) and the torch version. With --json the last line is one JSON object
with the medians (the times, psnr_db, height_mae_mm, object_height_mae_mm; with the simulator
height_mae_grid_mm, object_footprint_extra_px, object_footprint_missing_px,
object_footprint_iou and the per-bin medians height_mae_by_view_tilt_mm, psnr_by_view_tilt_db,
object_height_mae_by_view_tilt_mm, object_psnr_by_view_tilt_db, edge_psnr_by_view_tilt_db and
flat_psnr_by_view_tilt_db), the device fields and per_scene (with --cached: no times, no device,
and the scene count as episodes).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nerf_transporter import geometry, splits
from nerf_transporter.data.generate import add_imagery_option_argument
from nerf_transporter.device_info import describe_device, device_line
from nerf_transporter.evaluation.cache import ImageryCache
from nerf_transporter.evaluation.rollout import EvaluationSpec
from nerf_transporter.imagery import (
    ImageryConfig,
    fit_scene,
    height_mae_mm,
    psnr,
    render_views,
    resolve_device,
)
from nerf_transporter.imagery.metrics import OBJECT_HEIGHT, colour_edges, footprint_errors
from nerf_transporter.methods.mira import over_workspace
from nerf_transporter.sim import cameras

VIEW_TILT_BINS_DEG = (0, 10, 20, 30, 40, 90)
# (result key, `view_errors` key, label, unit) of the per-tilt figures
BY_VIEW_TILT = (
    ("height_mae_by_view_tilt_mm", "workspace_height_mae_mm", "height MAE", "mm"),
    ("psnr_by_view_tilt_db", "workspace_psnr_db", "PSNR", "dB"),
    ("object_height_mae_by_view_tilt_mm", "object_height_mae_mm", "object height MAE", "mm"),
    ("object_psnr_by_view_tilt_db", "object_psnr_db", "object PSNR", "dB"),
    ("edge_psnr_by_view_tilt_db", "edge_psnr_db", "edge PSNR", "dB"),
    ("flat_psnr_by_view_tilt_db", "flat_psnr_db", "PSNR off edges", "dB"),
)


def view_tilt_deg(roll: float, pitch: float) -> float:
    """The angle (deg) between view (roll, pitch)'s axis and the vertical: the z axis of
    Ry(pitch) . Rx(roll) has z component cos(roll) cos(pitch)."""
    return float(np.degrees(np.arccos(np.cos(roll) * np.cos(pitch))))


def mean_by_view_tilt(grid: np.ndarray, values: list[float]) -> dict[str, float]:
    """'<low>-<high>' deg -> the mean of `values` (one per view of `grid`) over the views whose
    tilt from the vertical lies in that bin of `VIEW_TILT_BINS_DEG`; NaN values (a view without
    object pixels) are left out, and so are bins without values."""
    tilts = [round(view_tilt_deg(roll, pitch), 6) for roll, pitch in grid]  # 20 deg is 19.99...
    bins = {}
    for low, high in pairwise(VIEW_TILT_BINS_DEG):
        inside = [
            value
            for value, tilt in zip(values, tilts, strict=True)
            if low <= tilt < high and not np.isnan(value)
        ]
        if inside:
            bins[f"{low}-{high}"] = float(np.mean(inside))
    return bins


@dataclass(frozen=True)
class CameraBand:
    """A NeRF rig under study: `count` cameras on one spiral turn around `centre`,
    `horizontal_radius` from it, their heights rising from `heights[0]` to `heights[1]` (m), each
    aimed at `centre`; 480 x 640 images, focal 450 (the default rig's)."""

    count: int
    centre: tuple[float, float, float]
    horizontal_radius: float
    heights: tuple[float, float]

    def cameras(self) -> list[cameras.Camera]:
        intrinsics = cameras.intrinsics_matrix(450.0, cameras.IMAGE_SIZE)
        rig = []
        for k in range(self.count):
            azimuth = 2 * np.pi * k / self.count
            height = self.heights[0] + (self.heights[1] - self.heights[0]) * k / max(
                self.count - 1, 1
            )
            eye = np.array(self.centre) + np.array(
                [
                    self.horizontal_radius * np.cos(azimuth),
                    self.horizontal_radius * np.sin(azimuth),
                    height,
                ]
            )
            pose = cameras.look_at(eye, self.centre)
            rig.append(cameras.Camera(intrinsics, pose, cameras.IMAGE_SIZE))
        return rig


# The NeRF rigs a candidate can be captured with; "default" is the world's (`cameras.nerf_cameras`:
# 30 cameras 1.05 m from (0.5, 0, 0), elevations 35 -> 75 deg). "mira36" and "mira30" are MIRA's
# band (45 -> 57 deg elevation) with its 36 cameras or the paper's 30 images; "low30" puts the 30
# cameras where the steep views look from (27 -> 49 deg elevation, around the workspace centre).
RIGS: dict[str, CameraBand | None] = {
    "default": None,
    "mira36": CameraBand(36, (0.25, 0.0, 0.0), 0.75, (0.75, 1.15)),
    "mira30": CameraBand(30, (0.25, 0.0, 0.0), 0.75, (0.75, 1.15)),
    "low30": CameraBand(30, (0.5, 0.0, 0.0), 0.9, (0.45, 1.05)),
}


def view_errors(
    colour: np.ndarray,
    height: np.ndarray,
    truth_colour: np.ndarray,
    truth_height: np.ndarray,
    view_rotation: np.ndarray,
    pixel_size: float,
) -> dict[str, float]:
    """One view's height MAE (mm) and PSNR (dB) over the workspace, on its object pixels, at its
    colour edges and off them.

    Workspace pixels are those whose true surface point lies over the workspace; object pixels are
    the workspace pixels whose true surface point stands more than `OBJECT_HEIGHT` above the table
    in the world (a tilted view's height is along its own axis, so the table itself is not at
    height 0 there); edge pixels the workspace pixels at the true colour's edges (`colour_edges`),
    flat ones the others. A region's figures are NaN for a view without pixels in it.
    """
    pixels = np.stack(np.indices(np.shape(truth_height)), axis=-1)
    surface = geometry.view_to_world(
        geometry.pixel_to_world(pixels, truth_height, pixel_size), view_rotation
    )
    workspace = over_workspace(surface)
    objects = workspace & (surface[..., 2] > OBJECT_HEIGHT)
    edges = colour_edges(truth_colour)
    errors = {}
    regions = {
        "workspace": workspace,
        "object": objects,
        "edge": workspace & edges,
        "flat": workspace & ~edges,
    }
    for name, mask in regions.items():
        if mask.any():
            errors[f"{name}_height_mae_mm"] = height_mae_mm(height[mask], truth_height[mask])[0]
            errors[f"{name}_psnr_db"] = psnr(colour[mask], truth_colour[mask])
        else:
            errors[f"{name}_height_mae_mm"] = errors[f"{name}_psnr_db"] = float("nan")
    return errors


def _synchronize(config: ImageryConfig) -> None:
    device = resolve_device(config.device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def fit_and_render(nerf: dict, grid: np.ndarray, config: ImageryConfig) -> tuple[dict, tuple]:
    """Fit the views `nerf` (rgb, intrinsics, cam_to_world) and render `grid`: times, images."""
    start, cpu = time.perf_counter(), time.process_time()
    scene = fit_scene(nerf["rgb"], nerf["intrinsics"], nerf["cam_to_world"], config)
    _synchronize(config)
    fit_s, fit_cpu_s = time.perf_counter() - start, time.process_time() - cpu
    start, cpu = time.perf_counter(), time.process_time()
    images = render_views(scene, grid, config)
    render_s, render_cpu_s = time.perf_counter() - start, time.process_time() - cpu
    times = {"fit_s": fit_s, "render_s": render_s, "fit_render_s": fit_s + render_s}
    times |= {"fit_cpu_s": fit_cpu_s, "render_cpu_s": render_cpu_s}
    return times | {"fit_render_cpu_s": fit_cpu_s + render_cpu_s, "views": len(grid)}, images


def score_grid(
    colour: np.ndarray,
    height: np.ndarray,
    truth_colour: np.ndarray,
    truth_height: np.ndarray,
    grid: np.ndarray,
    pixel_size: float,
) -> dict:
    """The figures of imagery [V, ...] of view grid `grid` against the true views [V, ...]: PSNR
    of the top-down view and over the grid, height MAE (top-down, its objects, the grid), the
    top-down objects' footprint (`footprint_errors`) and the per-tilt means of `BY_VIEW_TILT`."""
    top = geometry.top_down_view_index(grid)
    psnrs = [psnr(colour[v], truth_colour[v]) for v in range(len(grid))]
    overall, on_objects = height_mae_mm(height[top], truth_height[top])
    grid_errors = [height_mae_mm(height[v], truth_height[v])[0] for v in range(len(grid))]
    per_view = [
        view_errors(
            colour[v],
            height[v],
            truth_colour[v],
            truth_height[v],
            geometry.tilt_matrix(*grid[v]),
            pixel_size,
        )
        for v in range(len(grid))
    ]
    by_tilt = {
        key: mean_by_view_tilt(grid, [errors[name] for errors in per_view])
        for key, name, _, _ in BY_VIEW_TILT
    }
    footprint = footprint_errors(height[top], truth_height[top])
    return {
        "psnr_db": psnrs[top],
        "psnr_grid_db": float(np.mean(psnrs)),
        "height_mae_mm": overall,
        "object_height_mae_mm": on_objects,
        "height_mae_grid_mm": float(np.mean(grid_errors)),
        **{f"object_footprint_{key}": value for key, value in footprint.items()},
        **by_tilt,
    }


def measure_scene(
    task: str, setting: str, seed: int, config: ImageryConfig, rig: CameraBand | None = None
) -> dict:
    """Fit scene `seed`'s NeRF views (captured by `rig`, or the world's rig) and score the view
    grid against the simulator's renders."""
    from nerf_transporter.sim import make_env  # PyBullet: not needed with --dataset

    env = make_env(task, setting, rigs=("nerf",), nerf_cameras=rig.cameras() if rig else None)
    try:
        obs, _ = env.reset(seed=seed)
        grid = geometry.view_grid(setting)
        truth = [env.render_orthographic(roll, pitch, config.pixel_size) for roll, pitch in grid]
    finally:
        env.close()
    times, (colour, height) = fit_and_render(obs["nerf"], grid, config)
    truth_colour, truth_height = (np.stack(images) for images in zip(*truth, strict=True))
    scores = score_grid(colour, height, truth_colour, truth_height, grid, config.pixel_size)
    return {"task": task, "seed": seed, **times, **scores}


def measure_cached_scene(
    cache: ImageryCache, nerf: EvaluationSpec, oracle: EvaluationSpec, seed: int
) -> dict:
    """Score the NeRF imagery of `nerf`'s scene `seed` against the simulator's (`oracle`'s), both
    read from the imagery cache: no fit, no simulator. SystemExit naming the command that builds
    the cache where a seed's imagery is not there."""
    loaded = {}
    for spec in (nerf, oracle):
        key = spec.imagery_key()
        loaded[spec.imagery] = cache.load(spec.task, spec.setting, seed, key)
        if loaded[spec.imagery] is None:
            options = "".join(
                f" --imagery-option {name}={value}" for name, value in nerf.imagery_options.items()
            )
            raise SystemExit(
                f"no cached {spec.imagery} imagery of {spec.task} ({spec.setting}) test seed {seed} "
                f"under {cache.root} (key {key}); build it with `nerf-transporter "
                f"evaluate-checkpoints ... --split test --imagery {spec.imagery}"
                + (options if spec.imagery == "nerf" else "")
                + "` or, for the imagery a config names, `nerf-transporter cache-imagery`"
            )
    colour, truth = loaded["nerf"], loaded["oracle"]
    if not np.array_equal(colour["views"], truth["views"]):
        raise SystemExit(f"seed {seed}: the cached NeRF and simulator views are of different grids")
    scores = score_grid(
        colour["colour"],
        colour["height"].astype(np.float32),
        truth["colour"],
        truth["height"].astype(np.float32),
        colour["views"],
        nerf.pixel_size,
    )
    return {"task": nerf.task, "seed": seed, **scores}


def truth_errors(colour: np.ndarray, height: np.ndarray, stored: Any) -> dict:
    """Mean PSNR and height errors of imagery [V, ...] on the views a NeRF dataset stores the
    simulator's renders of (`truth_view_ids`)."""
    views = stored["truth_view_ids"]
    truth_height = stored["truth_height"].astype(np.float32)
    errors = [height_mae_mm(height[v], truth_height[i]) for i, v in enumerate(views)]
    return {
        "psnr_db": float(
            np.mean([psnr(colour[v], stored["truth_colour"][i]) for i, v in enumerate(views)])
        ),
        "height_mae_mm": float(np.mean([overall for overall, _ in errors])),
        "object_height_mae_mm": float(np.nanmean([on_objects for _, on_objects in errors])),
    }


def dataset_config(dataset: Path, overrides: dict) -> ImageryConfig:
    """The imagery settings a NeRF dataset was made with (dataset.json), with `overrides`."""
    manifest = json.loads((dataset / "dataset.json").read_text())
    if manifest.get("imagery", {}).get("kind") != "nerf":
        raise SystemExit(f"{dataset} is not a NeRF-imagery dataset (dataset.json imagery.kind)")
    settings = manifest["imagery"]["config"]
    settings = {k: tuple(v) if isinstance(v, list) else v for k, v in settings.items()}
    return ImageryConfig(**(settings | overrides))


def measure_dataset_scene(episode: Path, config: ImageryConfig) -> dict:
    """Fit an episode's stored views again here; score it and the stored imagery on the truth."""
    stored = np.load(episode / "imagery.npz")
    times, (colour, height) = fit_and_render(
        dict(np.load(episode / "nerf_views.npz")), stored["views"], config
    )
    here = truth_errors(colour, height, stored)
    before = truth_errors(stored["colour"], stored["height"].astype(np.float32), stored)
    return {
        "task": episode.parent.name,
        "seed": int(episode.name.split("-")[-1]),
        **times,
        **here,
        **{f"stored_{key}": value for key, value in before.items()},
    }


def _by_tilt_text(result: dict) -> str:
    return "; ".join(
        f"{label} by view tilt: "
        + ", ".join(f"{name} deg {value:.2f} {unit}" for name, value in result[key].items())
        for key, _, label, unit in BY_VIEW_TILT
    )


def summarise(per_scene: list[dict], keys: tuple[str, ...], by_tilt: bool) -> dict:
    """The medians over the scenes of `keys` and, with `by_tilt`, of each `BY_VIEW_TILT` bin."""
    summary = {key: statistics.median(r[key] for r in per_scene) for key in keys}
    for key, _, _, _ in BY_VIEW_TILT if by_tilt else ():
        names = sorted(
            {name for r in per_scene for name in r[key]}, key=lambda n: float(n.split("-")[0])
        )
        summary[key] = {
            name: statistics.median(r[key][name] for r in per_scene if name in r[key])
            for name in names
        }
    return summary


SCORE_KEYS = (
    "psnr_db",
    "height_mae_mm",
    "object_height_mae_mm",
    "height_mae_grid_mm",
    "object_footprint_extra_px",
    "object_footprint_missing_px",
    "object_footprint_iou",
)


def score_cache(
    parser: argparse.ArgumentParser, args: argparse.Namespace, options: dict[str, Any]
) -> int:
    """`--cached`: the cached NeRF imagery (of the fit settings `options`) of each task's first
    test seeds against the simulator's."""
    cache = ImageryCache(args.cached)
    per_scene = []
    try:
        specs = [
            [
                EvaluationSpec(task, setting=args.setting, imagery=imagery, imagery_config=config)
                for imagery, config in (("nerf", options), ("oracle", None))
            ]
            for task in args.task
        ]
    except (TypeError, ValueError) as error:
        parser.error(str(error))
    for nerf, oracle in specs:
        print(
            f"{nerf.task} ({nerf.setting}): NeRF imagery {nerf.imagery_key()} against the "
            f"simulator's {oracle.imagery_key()}, under {cache.root}",
            flush=True,
        )
        for seed in (splits.split_seed("test", i) for i in range(args.episodes)):
            per_scene.append(measure_cached_scene(cache, nerf, oracle, seed))
    summary = summarise(per_scene, SCORE_KEYS, by_tilt=True)
    if args.json:
        print(json.dumps(summary | {"episodes": len(per_scene), "per_scene": per_scene}))
    else:
        medians = {key: summary[key] for key in SCORE_KEYS}
        print(
            f"medians of {len(per_scene)} scenes: "
            + ", ".join(f"{key} {value:.2f}" for key, value in medians.items())
        )
        print("medians, " + _by_tilt_text(summary))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", nargs="+", default=["block-insertion"])
    parser.add_argument("--setting", default="normal")
    parser.add_argument("--episodes", type=int, default=2, help="scenes per task (test seeds)")
    parser.add_argument(
        "--dataset",
        type=Path,
        action="append",
        help="a NeRF dataset folder whose first --episodes episodes to fit again (repeatable; "
        "replaces --task)",
    )
    parser.add_argument("--iterations", type=int, default=None, help="override the fit iterations")
    add_imagery_option_argument(
        parser, "an ImageryConfig field for the fit (repeatable), as `generate --imagery-option`"
    )
    parser.add_argument(
        "--rig",
        choices=list(RIGS),
        default="default",
        help="the NeRF rig that captures the scenes (not with --dataset, whose views are stored)",
    )
    parser.add_argument(
        "--cached",
        type=Path,
        metavar="CACHE_DIR",
        help="score the NeRF imagery (of --imagery-option) already in this imagery cache against "
        "the simulator's imagery cached beside it, on the first --episodes test seeds of each "
        "--task: no fit, no simulator, no times (e.g. data/imagery-cache)",
    )
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--device", default="auto", help="auto (CUDA when available), cpu, cuda")
    parser.add_argument("--json", action="store_true", help="last line: one JSON object")
    args = parser.parse_args(argv)

    options = dict(args.imagery_option)
    if args.iterations is not None:
        options["iterations"] = args.iterations
    overrides = options | {"progress": False, "threads": args.threads, "device": args.device}
    datasets = args.dataset or []
    if datasets and args.rig != "default":
        parser.error("--rig: a dataset's views are stored; the rig applies to --task scenes")
    if args.cached and (datasets or args.rig != "default"):
        parser.error("--cached scores cached imagery of --task scenes: no --dataset, no --rig")
    if args.cached:
        return score_cache(parser, args, options)
    try:
        config = dataset_config(datasets[0], overrides) if datasets else ImageryConfig(**overrides)
    except (TypeError, ValueError) as error:
        parser.error(f"--imagery-option: {error}")
    if args.threads:
        torch.set_num_threads(args.threads)
    device = describe_device(resolve_device(config.device))
    print(device_line(device), flush=True)
    per_scene = []
    for dataset in datasets:
        config = dataset_config(dataset, overrides)
        episodes = sorted(path for path in dataset.iterdir() if (path / "imagery.npz").exists())
        for episode in episodes[: args.episodes]:
            result = measure_dataset_scene(episode, config)
            per_scene.append(result)
            print(
                f"{dataset.name} {episode.name}: fit {result['fit_s']:.1f} s, render "
                f"{result['views']} views {result['render_s']:.1f} s; on the truth views: PSNR "
                f"{result['psnr_db']:.2f} dB (stored {result['stored_psnr_db']:.2f}), height MAE "
                f"{result['height_mae_mm']:.2f} mm (stored {result['stored_height_mae_mm']:.2f}), "
                f"objects {result['object_height_mae_mm']:.2f} mm "
                f"(stored {result['stored_object_height_mae_mm']:.2f})",
                flush=True,
            )
    for task in [] if datasets else args.task:
        for seed in (splits.split_seed("test", i) for i in range(args.episodes)):
            result = measure_scene(task, args.setting, seed, config, RIGS[args.rig])
            per_scene.append(result)
            print(
                f"{task} seed {seed}: fit {result['fit_s']:.1f} s (CPU {result['fit_cpu_s']:.1f}), "
                f"render {result['views']} views {result['render_s']:.1f} s "
                f"(CPU {result['render_cpu_s']:.1f}), PSNR top-down {result['psnr_db']:.2f} dB "
                f"(grid {result['psnr_grid_db']:.2f}), height MAE {result['height_mae_mm']:.2f} mm "
                f"(objects {result['object_height_mae_mm']:.2f}, grid {result['height_mae_grid_mm']:.2f}; "
                + _by_tilt_text(result)
                + ")",
                flush=True,
            )
    keys = ("fit_s", "render_s", "fit_render_s", "fit_cpu_s", "render_cpu_s", "fit_render_cpu_s")
    if datasets:
        keys += ("psnr_db", "height_mae_mm", "object_height_mae_mm")
        keys += ("stored_psnr_db", "stored_height_mae_mm", "stored_object_height_mae_mm")
    else:
        keys += SCORE_KEYS
    summary = summarise(per_scene, keys, by_tilt=not datasets)
    medians = {key: summary[key] for key in keys}
    summary.update(device=device, per_scene=per_scene)
    if args.json:
        print(json.dumps(summary))
    else:
        print("medians: " + ", ".join(f"{key} {value:.2f}" for key, value in medians.items()))
        if not datasets:
            print("medians, " + _by_tilt_text(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
