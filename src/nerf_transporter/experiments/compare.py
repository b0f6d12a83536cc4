"""`nerf-transporter compare-cells FIRST OTHER [...]`: cells tested on one task and setting, paired
on their common test seeds, e.g. one method under two budgets, fitted on two machines, or trained
in two settings (a Challenging-trained cell against the Normal fit's Challenging test). Besides
run-cell's cells it reads the test records `nerf-transporter evaluate-checkpoints --split test`
writes into a run's `evaluation/` (e.g. a checkpoint tested on more seeds than its cell). Each
file is checked as `experiments/cells.py` checks cells, and all must come from one world: this
checkout's, or one archived world's (`results/archive/world-<fingerprint>/`).

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


def comparison_table(cells: list[dict]) -> tuple[list[str], list[list[str]]]:
    """The first cell, then each other one against it on their common test seeds."""
    tested = {(record["task"], record["setting"]) for record in cells}
    if len(tested) > 1:
        names = ", ".join(sorted(column_name(*pair) for pair in tested))
        raise ValueError(
            f"the cells were tested on different tasks or settings ({names}): compare cells "
            "tested alike"
        )
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
        description="Cells tested on one task and setting (trained in either), paired on their "
        "common test seeds: how many seeds both, only the first, only the other and neither "
        "succeeded on, and the exact McNemar p-value.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "cells",
        nargs="+",
        type=Path,
        help="two or more cell files (results/<column>/<row>.json) or test records "
        "(<run>/evaluation/<checkpoint>-test-<setting>.json)",
    )
    args = parser.parse_args(argv)
    try:
        if len(args.cells) < 2 or not all(path.is_file() for path in args.cells):
            raise ValueError("give two or more cell files or test records")
        header, rows = comparison_table(load_tested(args.cells))
    except (OSError, ValueError) as error:
        print(f"nerf-transporter compare-cells: {error}", file=sys.stderr)
        return 2
    sys.stdout.write(markdown(header, rows))
    return 0
