"""Success and missed picks of hanging-disks cells by the colour of each test scene's disk.

hanging-disks draws the disk's colour from the anchor's training colours for training and
validation seeds and from its evaluation colours for test seeds, four of which no training seed
has (`sim/tasks/hanging_disks.py`); the stand is always brown. This replays each test seed's reset
(no robot motion) to read the colour it drew, and breaks every cell's recorded test outcomes down
by the disk's colour, to show which colours a policy misses: each entry is the successes over the
episodes and, in brackets, the picks that touched nothing (the episode's failure "pick: the suction
tip touched no movable object"). Test records of `evaluate-checkpoints` (one checkpoint on
another imagery, `--imagery oracle` or `--imagery-option ...`) are rows too, named by their file.
Every file named is a row (two fits of one row, a sweep's beside the table's, with the file's path
where their labels agree); a folder gives the newest cell of each of its rows, as the table does.
The cells must be of this checkout's world, whose seeds build the scenes replayed here.

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/hanging_disk_colours.py \
        results/hanging-disks/*.json [--seeds 60] [--json]

docs/failures.md reports and reads these figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

from nerf_transporter.experiments.failures import records_of_task
from nerf_transporter.experiments.report import seed_outcomes
from nerf_transporter.sim import make_env
from nerf_transporter.sim.tasks.hanging_disks import TEST_COLORS

TASK = "hanging-disks"
MISSED_PICK = "pick: the suction tip touched no movable object"


def scene_colours(seeds: list[int]) -> dict[int, dict[str, str]]:
    """seed -> {"disk": colour name, "stand": colour name} as the task draws them at reset."""
    env = make_env(TASK)
    try:
        colours = {}
        for seed in seeds:
            env.reset(seed=seed)
            colours[seed] = dict(env.task.colors)
        return colours
    finally:
        env.close()


def cell_label(cell: dict) -> str:
    """The cell's row, with `+colour` where it was trained with colour augmentation and its
    training steps and learning rate where it was (a sweep's cells differ in those); a test
    record's row is its file's name and the imagery it was tested on."""
    if "protocol" not in cell:
        options = "".join(f" {k}={v}" for k, v in sorted(cell.get("imagery_options", {}).items()))
        return f"{Path(cell['path']).stem} ({cell['imagery']} imagery{options})"
    row = f"{cell['method']}-oracle" if cell.get("imagery") == "oracle" else cell["method"]
    protocol = cell["protocol"]
    if not protocol.get("colour_augment"):
        return row
    return f"{row} +colour ({protocol['steps']} steps, lr {protocol['lr']:g})"


def by_disk_colour(cell: dict, colours: dict[int, dict[str, str]]) -> dict[str, list[int]]:
    """disk colour -> [successes, episodes, missed picks] over the cell's test episodes (erred
    episodes left out)."""
    counts = {colour: [0, 0, 0] for colour in TEST_COLORS}
    for episode in cell["episode_results"]:
        if episode.get("error"):
            continue
        tally = counts[colours[episode["seed"]]["disk"]]
        tally[0] += int(episode["success"])
        tally[1] += 1
        tally[2] += int(episode.get("failure") == MISSED_PICK)
    return counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "cells",
        type=Path,
        nargs="+",
        help="hanging-disks cell files or folders, or test record files",
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="only the test seeds below this one in every row (e.g. 60: the first 30 test "
        "seeds), to set a cell beside a record of its first episodes",
    )
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    args = parser.parse_args(argv)
    try:
        cells = records_of_task(args.cells, TASK)
    except (OSError, ValueError) as error:  # a cell or record it cannot read, or none of TASK
        print(f"hanging_disk_colours.py: {error}", file=sys.stderr)
        return 2
    if args.seeds is not None:
        cells = [
            cell
            | {"episode_results": [e for e in cell["episode_results"] if e["seed"] < args.seeds]}
            for cell in cells
        ]
    seeds = sorted({seed for cell in cells for seed in seed_outcomes(cell)})
    colours = scene_colours(seeds)
    scenes = {c: sum(colours[s]["disk"] == c for s in seeds) for c in TEST_COLORS}
    header = " | ".join(f"{c} disk ({scenes[c]} scenes)" for c in TEST_COLORS)
    print(f"| cell | all | {header} |\n| --- | --- |{' --- |' * len(TEST_COLORS)}")
    summary = []
    labels = Counter(cell_label(cell) for cell in cells)
    for cell in cells:
        counts = by_disk_colour(cell, colours)
        wins, missed = (sum(tally[k] for tally in counts.values()) for k in (0, 2))
        parts = " | ".join(f"{s}/{n} ({m})" for s, n, m in counts.values())
        label = cell_label(cell)
        label = f"{label}, {cell['path']}" if labels[label] > 1 else label
        print(f"| {label} | {wins}/{len(seed_outcomes(cell))} ({missed}) | {parts} |")
        summary.append({"cell": str(cell["path"]), "label": label, "by_disk": counts})
    if args.json:
        print(json.dumps({"colours": {str(s): colours[s] for s in seeds}, "cells": summary}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
