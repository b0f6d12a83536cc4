"""Mental-imagery benchmark: fit time, 49-view render time and quality against the simulator.

    python benchmarks/imagery.py --task block-insertion --episodes 2 --json
    python benchmarks/imagery.py --dataset data/block-insertion-normal-train --episodes 4

With `--dataset` (no simulator needed: a GPU machine without PyBullet) the scenes are a NeRF
dataset's episodes: their stored 30 RGB views are fitted again with the dataset's own imagery
settings on this device, and the truth is the simulator's renders stored beside the imagery
(`truth_view_ids`, the pick and place views); the stored imagery, fitted where the dataset was made,
is scored against the same truth, so the two fits compare on identical inputs.

Per scene: fit seconds, render seconds for the whole view grid, PSNR of the top-down view and the
mean over the grid, height MAE (mm) overall and on object pixels (top-down view), and with the
simulator the grid's height MAE and PSNR by view tilt (the view's axis from the vertical, bins of
`VIEW_TILT_BINS_DEG`: the 7 x 7 Normal grid reaches 41 deg, the 11 x 11 Challenging one 60) on the
pixels whose true surface lies over the workspace, those mira places at (`pixels_over_workspace`).
The steepest views' image borders see past the workspace, where the simulator and the NeRF's floor
disagree by up to metres: the grid's all-pixel figure (height_mae_grid_mm) counts them, the
per-tilt one does not. Times are wall
seconds, and also process CPU seconds (fit_cpu_s, render_cpu_s), steadier than wall time on a
shared machine (meaningless for GPU work, which they miss). The first line
names the device (GPU name, or CPU model and torch threads) and the torch version. With --json the
last line is one JSON object with the medians (fit_s, render_s, fit_cpu_s, render_cpu_s, psnr_db,
height_mae_mm, object_height_mae_mm; with the simulator height_mae_grid_mm and the per-bin medians
height_mae_by_view_tilt_mm and psnr_by_view_tilt_db), the device fields and per_scene.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nerf_transporter import geometry, splits
from nerf_transporter.device_info import describe_device, device_line
from nerf_transporter.imagery import (
    ImageryConfig,
    fit_scene,
    height_mae_mm,
    psnr,
    render_views,
    resolve_device,
)
from nerf_transporter.methods.mira import pixels_over_workspace

VIEW_TILT_BINS_DEG = (0, 10, 20, 30, 40, 90)


def view_tilt_deg(roll: float, pitch: float) -> float:
    """The angle (deg) between view (roll, pitch)'s axis and the vertical: the z axis of
    Ry(pitch) . Rx(roll) has z component cos(roll) cos(pitch)."""
    return float(np.degrees(np.arccos(np.cos(roll) * np.cos(pitch))))


def mean_by_view_tilt(grid: np.ndarray, values: list[float]) -> dict[str, float]:
    """'<low>-<high>' deg -> the mean of `values` (one per view of `grid`) over the views whose
    tilt from the vertical lies in that bin of `VIEW_TILT_BINS_DEG` (bins without views left out)."""
    tilts = [round(view_tilt_deg(roll, pitch), 6) for roll, pitch in grid]  # 20 deg is 19.99...
    bins = {}
    for low, high in pairwise(VIEW_TILT_BINS_DEG):
        inside = [value for value, tilt in zip(values, tilts, strict=True) if low <= tilt < high]
        if inside:
            bins[f"{low}-{high}"] = float(np.mean(inside))
    return bins


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
    times = {"fit_s": fit_s, "render_s": render_s, "fit_cpu_s": fit_cpu_s}
    return times | {"render_cpu_s": render_cpu_s, "views": len(grid)}, images


def measure_scene(task: str, setting: str, seed: int, config: ImageryConfig) -> dict:
    from nerf_transporter.sim import make_env  # PyBullet: not needed with --dataset

    env = make_env(task, setting, rigs=("nerf",))
    try:
        obs, _ = env.reset(seed=seed)
        grid = geometry.view_grid(setting)
        truth = [env.render_orthographic(roll, pitch, config.pixel_size) for roll, pitch in grid]
    finally:
        env.close()
    times, (colour, height) = fit_and_render(obs["nerf"], grid, config)
    top = geometry.top_down_view_index(grid)
    psnrs = [psnr(colour[v], truth[v][0]) for v in range(len(grid))]
    overall, on_objects = height_mae_mm(height[top], truth[top][1])
    grid_errors = [height_mae_mm(height[v], truth[v][1])[0] for v in range(len(grid))]
    inside = [
        pixels_over_workspace(truth[v][1], geometry.tilt_matrix(*grid[v]), config.pixel_size)
        for v in range(len(grid))
    ]
    workspace_errors = [
        height_mae_mm(height[v][inside[v]], truth[v][1][inside[v]])[0] for v in range(len(grid))
    ]
    workspace_psnrs = [psnr(colour[v][inside[v]], truth[v][0][inside[v]]) for v in range(len(grid))]
    return {
        "task": task,
        "seed": seed,
        **times,
        "psnr_db": psnrs[top],
        "psnr_grid_db": float(np.mean(psnrs)),
        "height_mae_mm": overall,
        "object_height_mae_mm": on_objects,
        "height_mae_grid_mm": float(np.mean(grid_errors)),
        "height_mae_by_view_tilt_mm": mean_by_view_tilt(grid, workspace_errors),
        "psnr_by_view_tilt_db": mean_by_view_tilt(grid, workspace_psnrs),
    }


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


BY_VIEW_TILT = (
    ("height_mae_by_view_tilt_mm", "height MAE", "mm"),
    ("psnr_by_view_tilt_db", "PSNR", "dB"),
)


def _by_tilt_text(result: dict) -> str:
    return "; ".join(
        f"{label} by view tilt: "
        + ", ".join(f"{name} deg {value:.2f} {unit}" for name, value in result[key].items())
        for key, label, unit in BY_VIEW_TILT
    )


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
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--device", default="auto", help="auto (CUDA when available), cpu, cuda")
    parser.add_argument("--json", action="store_true", help="last line: one JSON object")
    args = parser.parse_args(argv)

    overrides = {"progress": False, "threads": args.threads, "device": args.device}
    if args.iterations is not None:
        overrides["iterations"] = args.iterations
    datasets = args.dataset or []
    config = dataset_config(datasets[0], overrides) if datasets else ImageryConfig(**overrides)
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
            result = measure_scene(task, args.setting, seed, config)
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
    keys = ("fit_s", "render_s", "fit_cpu_s", "render_cpu_s", "psnr_db", "height_mae_mm")
    keys += ("object_height_mae_mm",)
    if datasets:
        keys += ("stored_psnr_db", "stored_height_mae_mm", "stored_object_height_mae_mm")
    else:
        keys += ("height_mae_grid_mm",)
    summary = {key: statistics.median(r[key] for r in per_scene) for key in keys}
    medians = dict(summary)
    for key, _, _ in [] if datasets else BY_VIEW_TILT:
        summary[key] = {
            name: statistics.median(r[key][name] for r in per_scene) for name in per_scene[0][key]
        }
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
