"""Label round trip in the simulator: stored oracle demo -> labels -> action -> success?

For each task, generates (or reuses) the first N successful train demos with oracle imagery, turns
each oracle action into the labels the methods learn from, rebuilds an action from those labels and
the stored imagery heights alone (as a policy that predicted the labels exactly would), executes it
on the same seed and reports the success rate:

- `mira`: top-down pick pixel + height, place view + pixel + height of that view, rotation bin;
- `heightmap`: top-down pixels, rotation bin, place z, roll and pitch (pick height from the view).

    python benchmarks/label_round_trip.py --demos 20 [--tasks block-insertion ...]
        [--pixel-size 0.00625 --rotations 12] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.data import episode as ep
from nerf_transporter.data.generate import GenerationConfig, action_from_meta, generate_dataset
from nerf_transporter.data.labels import (
    action_from_labels,
    heightmap_labels,
    mira_labels,
)
from nerf_transporter.sim import TASKS, make_env
from nerf_transporter.sim.tasks import pose_error_text


def rebuilt_actions(
    meta: dict, imagery: dict, grid: np.ndarray, pixel_size: float, n_rotations: int
) -> dict[str, dict]:
    """The actions a perfect policy of each label family would output for this demo."""
    action = action_from_meta(meta)
    height = imagery["height"].astype(np.float32)
    top = g.top_down_view_index(grid)
    mira = mira_labels(action, grid, pixel_size, n_rotations)
    flat = heightmap_labels(action, pixel_size, n_rotations)
    return {
        "mira": action_from_labels(
            mira.pick_pixel,
            height[top][mira.pick_pixel],
            mira.place_pixel,
            height[mira.place_view][mira.place_pixel],
            mira.rotation_bin,
            place_view=tuple(grid[mira.place_view]),
            pixel_size=pixel_size,
            n_rotations=n_rotations,
        ),
        "heightmap": action_from_labels(
            flat.pick_pixel,
            height[top][flat.pick_pixel],
            flat.place_pixel,
            flat.place_z,
            flat.rotation_bin,
            place_tilt=(flat.place_roll, flat.place_pitch),
            pixel_size=pixel_size,
            n_rotations=n_rotations,
        ),
    }


def measure(
    task: str,
    setting: str,
    demos: int,
    data_dir: str,
    pixel_size: float,
    n_rotations: int,
    workers: int,
) -> dict:
    config = GenerationConfig(task, setting, "train", "oracle", pixel_size, nerf_views=0)
    start = time.perf_counter()
    dataset = generate_dataset(config, demos, data_dir, workers=workers)
    generation_s = time.perf_counter() - start
    env = make_env(task, setting, rigs=("state",))
    results: dict[str, list] = {"mira": [], "heightmap": []}
    try:
        for ref in ep.list_episodes(dataset)[:demos]:
            episode = ep.load_episode(ref.path, ["imagery"])
            actions = rebuilt_actions(
                episode.meta, episode.arrays["imagery"], config.grid, pixel_size, n_rotations
            )
            for family, action in actions.items():
                env.reset(seed=ref.seed)
                _, _, _, _, info = env.step(action)
                results[family].append(
                    (ref.seed, bool(info["success"]), info.get("failure") or pose_error_text(info))
                )
    finally:
        env.close()
    summary = {
        "task": task,
        "setting": setting,
        "demos": len(results["mira"]),
        "pixel_size": pixel_size,
        "n_rotations": n_rotations,
        "oracle_failed_seeds": len(ep.failed_seeds(dataset)),
        "generation_s": round(generation_s, 1),
    }
    for family, rows in results.items():
        successes = sum(ok for _, ok, _ in rows)
        summary[f"{family}_successes"] = successes
        summary[f"{family}_rate"] = successes / max(len(rows), 1)
        summary[f"{family}_failed_seeds"] = {seed: reason for seed, ok, reason in rows if not ok}
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tasks", nargs="+", default=sorted(TASKS))
    parser.add_argument("--setting", default="normal")
    parser.add_argument("--demos", type=int, default=20)
    parser.add_argument("--data-dir", default="data/benchmarks")
    parser.add_argument("--pixel-size", type=float, default=g.PIXEL_SIZE)
    parser.add_argument("--rotations", type=int, default=g.N_ROTATIONS, help="rotation bins")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = [
        measure(
            task,
            args.setting,
            args.demos,
            args.data_dir,
            args.pixel_size,
            args.rotations,
            args.workers,
        )
        for task in args.tasks
    ]
    for row in rows:
        print(
            f"{row['task']:<20} {row['setting']:<8} demos {row['demos']:>3}  "
            f"mira {row['mira_successes']}/{row['demos']} ({100 * row['mira_rate']:.0f}%)  "
            f"heightmap {row['heightmap_successes']}/{row['demos']} ({100 * row['heightmap_rate']:.0f}%)  "
            f"oracle failures skipped {row['oracle_failed_seeds']}"
        )
        for family in ("mira", "heightmap"):
            for seed, reason in row[f"{family}_failed_seeds"].items():
                print(f"    {family} failed on seed {seed}: {reason}")
    if args.json:
        print(json.dumps(rows))


if __name__ == "__main__":
    main()
