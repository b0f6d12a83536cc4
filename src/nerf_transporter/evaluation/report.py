"""`nerf-transporter report logs/ [--csv]`: the results table (docs/conventions.md, "Evaluation protocol").

Reads every `results*.json` (written by `lightning test`, one per tested checkpoint) under the given
directories and prints one row per method and one column per task/setting; a cell reads
"rate% (n, CI)" with the 95% Wilson interval in percent, and is empty where no run exists. Where
several runs exist for one cell, the newest wins.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from pathlib import Path

from nerf_transporter.console import HelpFormatter

RESULTS_GLOB = "results*.json"
METHODS = {
    "gt_state_mlp": "GT-State MLP",
    "form2fit": "Form2Fit",
    "transporter_se2": "Transporter-SE(2)",
    "transporter_se3": "Transporter-SE(3)",
    "mira": "mira (ours)",
}
TASKS = ("block-insertion", "place-red-in-green", "hanging-disks", "stacking-kits")
SETTINGS = ("normal", "challenging", "flat")
# the columns of the paper's Table 1, always shown; other task/settings follow when results exist
COLUMNS = tuple((task, "normal") for task in TASKS) + (("place-red-in-green", "challenging"),)
REQUIRED_KEYS = ("method", "task", "setting", "episodes", "successes", "ci_low", "ci_high")


def load_results(roots: list[Path]) -> list[dict]:
    """Every results file under `roots`, each with its path under "path"."""
    records = []
    for root in roots:
        if not root.exists():
            raise FileNotFoundError(f"no such directory: {root}")
        for path in sorted(root.rglob(RESULTS_GLOB)):
            try:
                record = json.loads(path.read_text())
            except (OSError, json.JSONDecodeError) as error:
                raise ValueError(f"unreadable results file {path}: {error}") from error
            missing = [key for key in REQUIRED_KEYS if key not in record]
            if missing:
                raise ValueError(f"results file {path} lacks {', '.join(missing)}")
            records.append(record | {"path": str(path)})
    return records


def column_name(task: str, setting: str) -> str:
    return task if setting == "normal" else f"{task} {setting.capitalize()}"


def cell(record: dict) -> str:
    """'rate% (n, low-high)' with percentages rounded to integers; '; k erred' appended when
    episodes erred (they are not in n)."""
    episodes, errors = record["episodes"], record.get("errors", 0)
    erred = f"; {errors} erred" if errors else ""
    if episodes == 0:
        return f"- (0{erred})"
    rate = round(100 * record["successes"] / episodes)
    low, high = round(100 * record["ci_low"]), round(100 * record["ci_high"])
    return f"{rate}% ({episodes}, {low}-{high}{erred})"


def _rank(value: str, known: tuple[str, ...]) -> tuple[int, str]:
    return (known.index(value), "") if value in known else (len(known), value)


def results_table(records: list[dict]) -> tuple[list[str], list[list[str]]]:
    """(header, rows): the newest record per (method, task, setting) in its cell."""
    newest: dict[tuple[str, str, str], dict] = {}
    for record in sorted(records, key=lambda r: (r.get("created", ""), r["path"])):
        newest[(record["method"], record["task"], record["setting"])] = record
    extra = {(task, setting) for _, task, setting in newest} - set(COLUMNS)
    columns = list(COLUMNS) + sorted(
        extra, key=lambda column: (_rank(column[0], TASKS), _rank(column[1], SETTINGS))
    )
    found = {method for method, _, _ in newest}
    methods = list(METHODS) + sorted(found - set(METHODS))
    header = ["method"] + [column_name(task, setting) for task, setting in columns]
    rows = []
    for method in methods:
        cells = [
            cell(newest[(method, task, setting)]) if (method, task, setting) in newest else ""
            for task, setting in columns
        ]
        rows.append([METHODS.get(method, method)] + cells)
    return header, rows


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def csv_text(header: list[str], rows: list[list[str]]) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return buffer.getvalue()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter report",
        description="Print the success-rate table (rate% (episodes, 95% Wilson CI)) from the "
        "results files (results*.json) that `lightning test` wrote under the given directories.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "roots", nargs="*", default=["logs"], help="folders searched for results*.json"
    )
    parser.add_argument("--csv", action="store_true", help="CSV instead of a markdown table")
    args = parser.parse_args(argv)
    try:
        records = load_results([Path(root) for root in args.roots])
    except (FileNotFoundError, ValueError) as error:
        print(f"nerf-transporter report: {error}", file=sys.stderr)
        return 1
    if not records:
        roots = " ".join(str(root) for root in args.roots)
        print(
            f"nerf-transporter report: no results*.json under {roots}; run "
            "`lightning test --config <config> --ckpt_path <ckpt>` first",
            file=sys.stderr,
        )
        return 1
    header, rows = results_table(records)
    sys.stdout.write(csv_text(header, rows) if args.csv else markdown(header, rows))
    return 0
