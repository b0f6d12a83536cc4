"""Data pipeline speed: episodes per hour (oracle and NeRF imagery) and training samples per second
from RavensDataModule (mira and transporter_se2 batches).

    python benchmarks/data.py [--task block-insertion] [--oracle-episodes 3] [--nerf-episodes 1]
                              [--pixel-size 0.003125] [--imagery-option iterations=400 ...] [--json]

Episodes per hour count the wall time of a generation run divided into the successful episodes it
wrote (failed oracle rollouts included, as a real run pays for them). Generation runs in a fresh
temporary directory unless --data-dir is given.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.data import episode as ep
from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.data.generate import GenerationConfig, generate_dataset, imagery_option

INPUT_KIND_OF = {"mira": "imagery", "transporter_se2": "heightmap"}


def generation_speed(config: GenerationConfig, episodes: int, data_dir: Path, workers: int) -> dict:
    start = time.perf_counter()
    dataset = generate_dataset(config, episodes, data_dir, workers=workers, progress=False)
    seconds = time.perf_counter() - start
    metas = [ep.read_meta(ref.path) for ref in ep.list_episodes(dataset)]
    stages = {
        name: float(np.mean([m["timings_s"][name] for m in metas]))
        for name in ("capture", "ground_truth_views", "rollout", "imagery", "total")
    }
    return {
        "imagery": config.imagery,
        "episodes": len(metas),
        "failed_seeds": len(ep.failed_seeds(dataset)),
        "wall_s": round(seconds, 1),
        "episodes_per_hour": round(3600.0 * len(metas) / seconds, 1),
        "mean_stage_s": {name: round(value, 2) for name, value in stages.items()},
        "quality": [m["imagery"]["quality"] for m in metas if m["imagery"]["quality"]],
    }


def sample_speed(
    method: str, config: GenerationConfig, episodes: int, data_dir: Path, args: argparse.Namespace
) -> dict:
    module = RavensDataModule(
        task=config.task,
        setting=config.setting,
        n_demos=episodes,
        data_dir=str(data_dir),
        batch_size=args.batch_size,
        num_workers=args.num_workers,
        imagery=config.imagery,
        pixel_size=config.pixel_size,
        n_negative_views=args.negative_views,
        nerf_views=config.nerf_views,
        generate_missing=False,
        input_kind=INPUT_KIND_OF[method],
        samples_per_epoch=args.samples,
    )
    start = time.perf_counter()
    module.setup("fit")
    setup_s = time.perf_counter() - start
    loader = module.train_dataloader()
    start = time.perf_counter()
    count = sum(len(batch["pick_pixel"]) for batch in loader)
    seconds = time.perf_counter() - start
    return {
        "method": method,
        "input_kind": INPUT_KIND_OF[method],
        "samples": count,
        "setup_s": round(setup_s, 2),
        "samples_per_s": round(count / seconds, 1),
        "batch_size": args.batch_size,
        "num_workers": args.num_workers,
        "augment": True,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="block-insertion")
    parser.add_argument("--setting", default="normal")
    parser.add_argument("--oracle-episodes", type=int, default=3)
    parser.add_argument("--nerf-episodes", type=int, default=1, help="0 skips the NeRF measurement")
    parser.add_argument("--pixel-size", type=float, default=g.PIXEL_SIZE)
    parser.add_argument("--nerf-views", type=int, default=30)
    parser.add_argument("--imagery-option", type=imagery_option, action="append", default=[])
    parser.add_argument("--workers", type=int, default=1, help="generation processes")
    parser.add_argument("--samples", type=int, default=64, help="samples drawn per method")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--num-workers", type=int, default=0, help="DataLoader workers")
    parser.add_argument("--negative-views", type=int, default=4)
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as temp:
        data_dir = args.data_dir or Path(temp)
        common = {
            "task": args.task,
            "setting": args.setting,
            "pixel_size": args.pixel_size,
            "nerf_views": args.nerf_views,
            "imagery_options": dict(args.imagery_option),
        }
        oracle = GenerationConfig(imagery="oracle", **common)
        results = {
            "generation": [generation_speed(oracle, args.oracle_episodes, data_dir, args.workers)]
        }
        if args.nerf_episodes > 0:
            nerf = GenerationConfig(imagery="nerf", **common)
            results["generation"].append(
                generation_speed(nerf, args.nerf_episodes, data_dir, args.workers)
            )
        results["training_samples"] = [
            sample_speed(method, oracle, args.oracle_episodes, data_dir, args)
            for method in INPUT_KIND_OF
        ]
    results["machine"] = {
        "cpu_count": os.cpu_count(),
        "task": args.task,
        "pixel_size": args.pixel_size,
    }

    for row in results["generation"]:
        print(
            f"generate --imagery {row['imagery']:<6} {row['episodes_per_hour']:>8.1f} episodes/hour "
            f"({row['episodes']} episodes, {row['failed_seeds']} failed seeds, {row['wall_s']} s; "
            f"mean stage s: {row['mean_stage_s']})"
        )
    for row in results["training_samples"]:
        print(
            f"DataModule {row['method']:<16} {row['samples_per_s']:>8.1f} samples/s "
            f"(batch {row['batch_size']}, {row['num_workers']} workers, augmented; setup {row['setup_s']} s)"
        )
    if args.json:
        print(json.dumps(results))


if __name__ == "__main__":
    main()
