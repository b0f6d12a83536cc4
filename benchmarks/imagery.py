"""Mental-imagery benchmark: fit time, 49-view render time and quality against the simulator.

    python benchmarks/imagery.py --task block-insertion --episodes 2 --json

Per scene: fit seconds, render seconds for the whole view grid, PSNR of the top-down view and the
mean over the grid, height MAE (mm) overall and on object pixels (top-down view). With --json the
last line is one JSON object with the medians (fit_s, render_s, psnr_db, height_mae_mm,
object_height_mae_mm) and per_scene.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
from device_info import describe_device, device_line

from nerf_transporter import geometry, splits
from nerf_transporter.imagery import ImageryConfig, fit_scene, height_mae_mm, psnr, render_views
from nerf_transporter.sim import make_env


def measure_scene(task: str, setting: str, seed: int, config: ImageryConfig) -> dict:
    env = make_env(task, setting, rigs=("nerf",))
    try:
        obs, _ = env.reset(seed=seed)
        grid = geometry.view_grid(setting)
        truth = [env.render_orthographic(roll, pitch, config.pixel_size) for roll, pitch in grid]
    finally:
        env.close()
    nerf = obs["nerf"]
    start = time.perf_counter()
    scene = fit_scene(nerf["rgb"], nerf["intrinsics"], nerf["cam_to_world"], config)
    fit_s = time.perf_counter() - start
    start = time.perf_counter()
    colour, height = render_views(scene, grid, config)
    render_s = time.perf_counter() - start
    top = geometry.top_down_view_index(grid)
    psnrs = [psnr(colour[v], truth[v][0]) for v in range(len(grid))]
    overall, on_objects = height_mae_mm(height[top], truth[top][1])
    grid_errors = [height_mae_mm(height[v], truth[v][1])[0] for v in range(len(grid))]
    return {
        "task": task,
        "seed": seed,
        "fit_s": fit_s,
        "render_s": render_s,
        "views": len(grid),
        "psnr_db": psnrs[top],
        "psnr_grid_db": float(np.mean(psnrs)),
        "height_mae_mm": overall,
        "object_height_mae_mm": on_objects,
        "height_mae_grid_mm": float(np.mean(grid_errors)),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", nargs="+", default=["block-insertion"])
    parser.add_argument("--setting", default="normal")
    parser.add_argument("--episodes", type=int, default=2, help="scenes per task (test seeds)")
    parser.add_argument("--iterations", type=int, default=None, help="override the fit iterations")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--json", action="store_true", help="last line: one JSON object")
    args = parser.parse_args(argv)

    overrides = {"progress": False, "threads": args.threads}
    if args.iterations is not None:
        overrides["iterations"] = args.iterations
    config = ImageryConfig(**overrides)
    per_scene = []
    for task in args.task:
        for seed in (splits.split_seed("test", i) for i in range(args.episodes)):
            result = measure_scene(task, args.setting, seed, config)
            per_scene.append(result)
            print(
                f"{task} seed {seed}: fit {result['fit_s']:.1f} s, render {result['views']} views "
                f"{result['render_s']:.1f} s, PSNR top-down {result['psnr_db']:.2f} dB "
                f"(grid {result['psnr_grid_db']:.2f}), height MAE {result['height_mae_mm']:.2f} mm "
                f"(objects {result['object_height_mae_mm']:.2f}, grid {result['height_mae_grid_mm']:.2f})",
                flush=True,
            )
    keys = ("fit_s", "render_s", "psnr_db", "height_mae_mm", "object_height_mae_mm")
    summary = {key: statistics.median(r[key] for r in per_scene) for key in keys}
    summary.update(device=describe_device(config.device), per_scene=per_scene)
    if args.json:
        print(json.dumps(summary))
    else:
        print("medians: " + ", ".join(f"{key} {summary[key]:.2f}" for key in keys))
        print(device_line(summary["device"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
