"""`nerf-transporter compare-cells FIRST OTHER [...]`: cells tested on one task and setting, paired
on their test seeds, e.g. one method under two budgets, fitted on two machines, or trained
in two settings (a Challenging-trained cell against the Normal fit's Challenging test). Besides
run-cell's cells it reads the test records `nerf-transporter evaluate-checkpoints --split test`
writes into a run's `evaluation/` (e.g. a checkpoint tested on more seeds than its cell). Each
file is checked as `experiments/cells.py` checks cells, and all must come from one world: this
checkout's, or one archived world's (`results/archive/world-<fingerprint>/`). Each must be tested
on the same seeds as the first; with `--allow-unequal-seeds` they are paired on the seeds both
tested. A line below the table says, for each, how many seeds were paired: those both tested,
less those that erred in either.

Two rates of 100 episodes each differ by chance by up to ~13 points; on the same seeds only the
seeds one cell succeeded on and the other failed decide between them (exact McNemar test,
`metrics.paired_comparison`). The first cell is compared with each other one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nerf_transporter.console import HelpFormatter
from nerf_transporter.evaluation.metrics import cell, paired_comparison
from nerf_transporter.experiments.cells import CellFileError, load_record, trained_setting
from nerf_transporter.experiments.report import (
    column_name,
    fit_machine_names,
    markdown,
    seed_outcomes,
)

HEADER = ["cell", "trained", "test", "checkpoint step", "fitted on", "seeds", "both", "first only"]
HEADER += ["this only", "neither", "p"]


def load_tested(paths: list[Path]) -> list[dict]:
    """Cells of run-cell and test records of evaluate-checkpoints, checked, each with its path;
    each must hold its episodes, and all must come from one world."""
    records = [load_record(path) for path in paths]
    for record in records:
        if "episode_results" not in record:
            raise CellFileError(f"{record['path']} holds no episode_results to pair on")
    if len({record["world"] for record in records}) > 1:
        worlds = ", ".join(f"{record['path']} in {record['world']}" for record in records)
        raise CellFileError(f"the cells were measured in different worlds ({worlds})")
    return records


def tested_seeds(record: dict) -> set[int]:
    """The seeds a record was tested on, erred ones included."""
    return {episode["seed"] for episode in record["episode_results"]}


def check_seed_sets(cells: list[dict]) -> None:
    """ValueError naming the first cell tested on other seeds than the first cell's."""
    first = tested_seeds(cells[0])
    for record in cells[1:]:
        seeds = tested_seeds(record)
        if seeds != first:
            raise ValueError(
                f"{record['path']} was tested on {len(seeds)} seeds, {cells[0]['path']} on "
                f"{len(first)}, {len(seeds & first)} of them common: pass --allow-unequal-seeds "
                "to pair them on the common seeds"
            )


def paired_lines(cells: list[dict]) -> list[str]:
    """For each cell after the first: how many seeds it was paired with the first on."""
    first, ran = tested_seeds(cells[0]), set(seed_outcomes(cells[0]))
    lines = []
    for record in cells[1:]:
        seeds = tested_seeds(record)
        paired = ran & set(seed_outcomes(record))
        lines.append(
            f"{record['path']}: paired on {len(paired)} seeds: the {len(seeds & first)} both were "
            f"tested on (this one {len(seeds)}, the first {len(first)}), less "
            f"{len(seeds & first) - len(paired)} that erred in either"
        )
    return lines


def comparison_table(
    cells: list[dict], allow_unequal_seeds: bool = False
) -> tuple[list[str], list[list[str]]]:
    """The first cell, then each other one against it on their common test seeds (refused where
    they were tested on other seeds than the first, unless `allow_unequal_seeds`)."""
    tested = {(record["task"], record["setting"]) for record in cells}
    if len(tested) > 1:
        names = ", ".join(sorted(column_name(*pair) for pair in tested))
        raise ValueError(
            f"the cells were tested on different tasks or settings ({names}): compare cells "
            "tested alike"
        )
    if not allow_unequal_seeds:
        check_seed_sets(cells)
    first = seed_outcomes(cells[0])
    rows = []
    for index, record in enumerate(cells):
        checkpoint = record.get("checkpoint")
        step = checkpoint["step"] if isinstance(checkpoint, dict) else record.get("global_step")
        described = [
            record["path"],
            trained_setting(record).capitalize(),
            cell(record),
            "-" if step is None else str(step),
            ", ".join(fit_machine_names(record)),
        ]
        if index == 0:
            rows.append(described + ["-"] * 6)
            continue
        paired = paired_comparison(first, seed_outcomes(record))
        counts = [str(paired[key]) for key in ("seeds", "both", "first_only", "second_only")]
        rows.append(described + counts + [str(paired["neither"]), f"{paired['p_value']:.2g}"])
    return HEADER, rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter compare-cells",
        description="Cells tested on one task and setting (trained in either) and on the same "
        "seeds, paired on those seeds: how many seeds both, only the first, only the other and "
        "neither succeeded on, and the exact McNemar p-value; below the table, how many seeds "
        "each was paired on.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "cells",
        nargs="+",
        type=Path,
        help="two or more cell files (results/<column>/<row>.json) or test records "
        "(<run>/evaluation/<checkpoint>-test-<setting>.json)",
    )
    parser.add_argument(
        "--allow-unequal-seeds",
        action="store_true",
        help="pair cells tested on other seeds than the first on the seeds both were tested on "
        "(default: refused)",
    )
    args = parser.parse_args(argv)
    try:
        if len(args.cells) < 2 or not all(path.is_file() for path in args.cells):
            raise ValueError("give two or more cell files or test records")
        cells = load_tested(args.cells)
        header, rows = comparison_table(cells, args.allow_unequal_seeds)
    except (OSError, ValueError) as error:
        print(f"nerf-transporter compare-cells: {error}", file=sys.stderr)
        return 2
    sys.stdout.write(markdown(header, rows) + "\n" + "\n".join(paired_lines(cells)) + "\n")
    return 0
