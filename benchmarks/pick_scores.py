"""Does a learnt pick see the object? Its attention's scores on the object against the empty table.

For each test scene of a cell, the checkpoint's attention logits on the top-down image of the
imagery the cell was tested on (read from the evaluation's imagery cache, never refitted here) and
on the simulator's own top-down render of the same scene: the highest logit over the object's
pixels and over the table's (the simulator's segmentation). A pick lands on the empty table
exactly where no object pixel scores above the table, so the rows split the scenes by where the
cell's recorded pick lay (on the empty table, as `failures` counts them, or not) and count the
scenes where the object scores below the table. The simulator's column tells a network that never learnt the object apart from
one that the imagery's departures tip over (docs/failures.md, "stacking-kits' mira refit on the
default imagery").

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/pick_scores.py \
        results/stacking-kits/mira.json \
        logs/sweep/stacking-kits/mira/RUN/version_0/checkpoints/step002000-success0.50.ckpt

The cell's test scenes must be in the imagery cache (`nerf-transporter cache-imagery --task TASK
--split test --episodes N`, or the cell's own test, fills it).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import numpy as np
import torch

from nerf_transporter import geometry
from nerf_transporter.data.preprocess import network_input
from nerf_transporter.evaluation.cache import ImageryCache
from nerf_transporter.evaluation.rollout import DEFAULT_CACHE_DIR, EvaluationSpec
from nerf_transporter.experiments.checkpoints import load_checkpoint
from nerf_transporter.experiments.failures import body_at, pick_pixel
from nerf_transporter.sim import make_env


def highest_scores(
    model: torch.nn.Module, colour: np.ndarray, height: np.ndarray, ids: np.ndarray, env
) -> tuple[float, float]:
    """(highest attention logit on the object's pixels, highest on the table's) of one image."""
    with torch.no_grad():
        logits = model.attention(network_input(colour, height)[None])[0].numpy()
    return (
        float(logits[ids == env.task.object_id].max()),
        float(logits[ids == env.table_id].max()),
    )


def scene_scores(
    cell: dict, model: torch.nn.Module, spec: EvaluationSpec, cache: ImageryCache
) -> list[dict]:
    """Per test episode of the cell: its seed, whether its recorded pick lay on the empty table,
    and the (object, table) highest logits on the cell's imagery and on the simulator's render."""
    env = make_env(cell["task"], cell["setting"])
    key = spec.imagery_key()
    scores = []
    try:
        for episode in cell["episode_results"]:
            if episode.get("error") or not episode.get("action"):
                continue
            seed = episode["seed"]
            imagery = cache.load(cell["task"], cell["setting"], seed, key)
            if imagery is None:
                raise FileNotFoundError(
                    f"seed {seed}'s imagery is not in the cache "
                    f"({cache.path(cell['task'], cell['setting'], seed, key)}); build it with "
                    f"`nerf-transporter cache-imagery --task {cell['task']} --split test ...`"
                )
            top = geometry.top_down_view_index(imagery["views"])
            env.reset(seed=seed)
            colour, height = env.render_orthographic(0.0, 0.0)
            ids, _ = env.render_segmentation_top_down()
            pick = pick_pixel(np.asarray(episode["action"]["pick"][:3]))
            scores.append(
                {
                    "seed": seed,
                    "pick_on_table": body_at(ids, pick) == env.table_id,
                    "imagery": highest_scores(
                        model, imagery["colour"][top], imagery["height"][top], ids, env
                    ),
                    "simulator": highest_scores(model, colour, height, ids, env),
                }
            )
    finally:
        env.close()
    return scores


def summary_rows(scores: list[dict]) -> list[str]:
    """Markdown rows: per group of scenes and imagery, the medians and the object-below counts."""
    rows = []
    for on_table, group in ((True, "picks on the empty table"), (False, "the other scenes")):
        chosen = [s for s in scores if s["pick_on_table"] == on_table]
        for source in ("imagery", "simulator"):
            pairs = [s[source] for s in chosen]
            if not pairs:
                continue
            cells = [
                f"{statistics.median(v):.1f} ({min(v):.1f} to {max(v):.1f})"
                for v in zip(*pairs, strict=True)
            ]
            below = sum(obj < table for obj, table in pairs)
            label = "the cell's" if source == "imagery" else "the simulator's"
            rows.append(f"| {group} ({len(chosen)}) | {label} | {' | '.join(cells)} | {below} |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("cell", type=Path, help="a cell file of the results table (run-cell)")
    parser.add_argument("checkpoint", type=Path, help="the checkpoint the cell was tested with")
    parser.add_argument("--cache-dir", default=DEFAULT_CACHE_DIR, help="the imagery cache")
    parser.add_argument("--json", type=Path, help="also write every scene's scores here")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    try:
        cell = json.loads(args.cell.read_text())
        model, datamodule = load_checkpoint(args.checkpoint, torch.device("cpu"))
        if not hasattr(model, "attention"):
            raise ValueError(f"{args.checkpoint}: {type(model).__name__} has no attention (pick)")
        spec = EvaluationSpec.from_datamodule(
            datamodule, split="test", setting=cell["setting"], imagery=cell.get("imagery")
        )
        scores = scene_scores(cell, model, spec, ImageryCache(args.cache_dir))
    except (OSError, ValueError, KeyError) as error:
        print(f"pick_scores.py: {error}", file=sys.stderr)
        return 2
    print(
        "| scenes | top-down image | highest logit on the object, median (range) | "
        "highest on the table | object below the table |\n| --- | --- | --- | --- | --- |"
    )
    print("\n".join(summary_rows(scores)))
    if args.json:
        args.json.write_text(json.dumps(scores))
    return 0


if __name__ == "__main__":
    sys.exit(main())
