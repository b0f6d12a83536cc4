"""`nerf-transporter dataset-info <dir> [--verify] [--json]`: what a dataset holds, and whether it is intact."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from nerf_transporter.console import HelpFormatter
from nerf_transporter.data import episode as ep


def _mean(values: list[float]) -> float | None:
    finite = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def dataset_summary(dataset_dir: str | Path, verify: bool = False) -> dict[str, Any]:
    """Episode count, seeds, failed seeds, imagery kind and quality; with `verify`, the problems
    (an unreadable meta.json or failed-seed record is one also without it)."""
    dataset_dir = Path(dataset_dir)
    config = ep.read_dataset_config(dataset_dir)
    if config is None:
        raise FileNotFoundError(f"{dataset_dir} is not a dataset: no {ep.DATASET_FILE}")
    refs = ep.list_episodes(dataset_dir)
    problems = [
        f"{path.name}: incomplete (temporary directory of an interrupted write)"
        for path in ep.stale_temp_dirs(dataset_dir)
    ]
    qualities: dict[str, list[float]] = {}
    for ref in refs:
        try:
            if verify:
                ep.verify_episode(ref.path)
            meta = ep.read_meta(ref.path)
        except ep.CorruptEpisodeError as error:
            problems.append(str(error))
            continue
        for name, value in ((meta.get("imagery") or {}).get("quality") or {}).items():
            qualities.setdefault(name, []).append(value)
    quality = {name: _mean(values) for name, values in qualities.items()} or None
    try:
        failed = ep.failed_seeds(dataset_dir)
    except ep.CorruptEpisodeError as error:  # a corrupt failed-seed record
        problems.append(str(error))
        failed = {}
    return {
        "dataset": str(dataset_dir),
        "task": config.get("task"),
        "setting": config.get("setting"),
        "split": config.get("split"),
        "imagery": (config.get("imagery") or {}).get("kind"),
        "pixel_size": config.get("pixel_size"),
        "episodes": len(refs),
        "seeds": [ref.seed for ref in refs],
        "failed_seeds": {str(seed): reason for seed, reason in sorted(failed.items())},
        "imagery_quality": quality,
        "verified": (not problems) if verify else None,
        "problems": problems,
    }


def format_summary(summary: dict[str, Any]) -> str:
    lines = [
        f"dataset   {summary['dataset']}",
        f"task      {summary['task']} ({summary['setting']}, {summary['split']} split)",
        f"imagery   {summary['imagery']} at {summary['pixel_size']} m per pixel",
        f"episodes  {summary['episodes']}",
        f"seeds     {', '.join(map(str, summary['seeds'])) or '-'}",
        f"failed    {len(summary['failed_seeds'])} seeds"
        + "".join(
            f"\n            {seed}: {reason}" for seed, reason in summary["failed_seeds"].items()
        ),
    ]
    if summary["imagery_quality"]:
        figures = ", ".join(
            f"{name} {value:.2f}"
            for name, value in summary["imagery_quality"].items()
            if value is not None
        )
        lines.append(f"quality   {figures} (mean over episodes, against ground truth)")
    if summary["verified"] is not None:
        lines.append(f"verified  {'yes' if summary['verified'] else 'NO'}")
    lines += [f"problem   {problem}" for problem in summary["problems"]]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter dataset-info",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "dataset", help="a dataset directory, e.g. data/block-insertion-normal-train"
    )
    parser.add_argument("--verify", action="store_true", help="check every file of every episode")
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    args = parser.parse_args(argv)
    try:
        summary = dataset_summary(args.dataset, verify=args.verify)
    except (FileNotFoundError, ep.DatasetConfigMismatchError) as error:
        print(f"nerf-transporter dataset-info: {error}", file=sys.stderr)
        return 2
    print(format_summary(summary))
    if args.json:
        print(json.dumps(summary))
    return 1 if summary["problems"] and args.verify else 0
