"""`nerf-transporter report results/ [--csv] [--plot PNG] [--readme README.md]`: the results table
(docs/conventions.md, "Evaluation protocol").

Reads the records under the given directories: the cells `run-cell` writes
(`<root>/<column>/<row>.json`) and every `results*.json` (`lightning test`, one per tested
checkpoint, anywhere below), and prints one row per method (`mira` with oracle imagery is a row of
its own) and one column per task/setting; a cell reads "rate% (n, CI)" with the 95% Wilson interval
in percent, and is empty where no run exists. Where several records exist for one cell, the newest
wins. Below each of our rows, the paper's Table 1 value of that method (`evaluation/paper.py`).
`--plot` draws the table as bars with their intervals and the paper's values as markers;
`--readme` rewrites the README's results block (between `README_START` and `README_END`).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from nerf_transporter.console import HelpFormatter
from nerf_transporter.drawing import bar_chart
from nerf_transporter.evaluation.paper import PAPER_COLUMNS, PAPER_SUCCESS

RESULTS_GLOB = "results*.json"
CELL_GLOB = "*/*.json"  # run-cell: <root>/<task>[-<setting>]/<method>[-oracle].json
# rows of the table, in order: the method's name, or `<method>-oracle` for oracle imagery
METHODS = {
    "mira": "mira (ours)",
    "mira-oracle": "mira, oracle imagery",
    "transporter_se2": "Transporter-SE(2)",
    "transporter_se3": "Transporter-SE(3)",
    "form2fit": "Form2Fit",
    "gt_state_mlp": "GT-State MLP",
}
PAPER_LABELS = {method: f"paper: {METHODS[method]}" for method in PAPER_SUCCESS} | {
    "mira": "paper: its method"
}
TASKS = ("block-insertion", "place-red-in-green", "hanging-disks", "stacking-kits")
SETTINGS = ("normal", "challenging", "flat")
# the columns of the paper's Table 1, always shown; other task/settings follow when results exist
COLUMNS = PAPER_COLUMNS
REQUIRED_KEYS = ("method", "task", "setting", "episodes", "successes", "ci_low", "ci_high")
README_START = "<!-- results table: written by `nerf-transporter report results/ --readme README.md`; do not edit -->"
README_END = "<!-- end of the results table -->"


def row_key(method: str, imagery: str | None) -> str:
    """The table row of a record: the method, `<method>-oracle` where it ran on oracle imagery."""
    return f"{method}-oracle" if imagery == "oracle" else method


def load_results(roots: list[Path]) -> list[dict]:
    """Every cell and results file under `roots`, each with its path under "path"."""
    records = []
    for root in roots:
        if not root.is_dir():
            raise FileNotFoundError(f"no such directory: {root}")
        for path in sorted(set(root.rglob(RESULTS_GLOB)) | set(root.glob(CELL_GLOB))):
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


def newest_records(records: list[dict]) -> dict[tuple[str, str, str], dict]:
    """(row, task, setting) -> the newest record of that cell (`row_key` names the row)."""
    newest: dict[tuple[str, str, str], dict] = {}
    for record in sorted(records, key=lambda r: (r.get("created", ""), r["path"])):
        row = row_key(record["method"], record.get("imagery"))
        newest[(row, record["task"], record["setting"])] = record
    return newest


def results_table(records: list[dict]) -> tuple[list[str], list[list[str]]]:
    """(header, rows): the newest record per (row, task, setting) in its cell; below each of our
    rows the paper's values of that method (empty cells where it has none)."""
    newest = newest_records(records)
    extra = {(task, setting) for _, task, setting in newest} - set(COLUMNS)
    columns = list(COLUMNS) + sorted(
        extra, key=lambda column: (_rank(column[0], TASKS), _rank(column[1], SETTINGS))
    )
    found = {row for row, _, _ in newest}
    methods = list(METHODS) + sorted(found - set(METHODS))
    header = ["method"] + [column_name(task, setting) for task, setting in columns]
    rows = []
    for method in methods:
        cells = [
            cell(newest[(method, task, setting)]) if (method, task, setting) in newest else ""
            for task, setting in columns
        ]
        rows.append([METHODS.get(method, method)] + cells)
        if method in PAPER_SUCCESS:
            paper = PAPER_SUCCESS[method]
            rows.append(
                [PAPER_LABELS[method]]
                + [f"{paper[column]}%" if column in paper else "" for column in columns]
            )
    return header, rows


def measured_cells(records: list[dict]) -> int:
    """How many of the table's rows x paper columns hold a record."""
    newest = newest_records(records)
    return sum((row, *column) in newest for row in METHODS for column in COLUMNS)


def table_plot(records: list[dict]) -> np.ndarray:
    """The table as grouped bars (one group per paper column, one bar per row) with their 95%
    intervals, and the paper's values as black diamonds; RGB uint8."""
    newest = newest_records(records)
    shape = (len(METHODS), len(COLUMNS))
    values, low, high, paper = (np.full(shape, np.nan) for _ in range(4))
    for i, row in enumerate(METHODS):
        for j, column in enumerate(COLUMNS):
            record = newest.get((row, *column))
            if record is not None and record["episodes"]:
                values[i, j] = record["successes"] / record["episodes"]
                low[i, j], high[i, j] = record["ci_low"], record["ci_high"]
            if column in PAPER_SUCCESS.get(row, {}):
                paper[i, j] = PAPER_SUCCESS[row][column] / 100
    return bar_chart(
        [column_name(*column) for column in COLUMNS],
        list(METHODS.values()),
        values,
        low,
        high,
        paper,
        title=f"Success with 95% Wilson interval, 10 demonstrations ({measured_cells(records)} "
        f"of {values.size} cells measured)",
        marker_label="paper (Table 1)",
    )


def readme_block(records: list[dict]) -> str:
    """The README's results block (without its markers): how many cells are measured, the table,
    and the plot where any cell is."""
    count, total = measured_cells(records), len(METHODS) * len(COLUMNS)
    header, rows = results_table(records)
    lines = [
        f"Full protocol (`nerf-transporter run-cell`, see below): {count} of {total} cells measured "
        "in `results/`.",
    ]
    if count == 0:
        lines[0] = (
            f"Full protocol (`nerf-transporter run-cell`, see below): no cell has been measured "
            f"yet (`results/` holds none of the {total}); the table shows the paper's values only."
        )
    lines += [
        "",
        markdown(header, rows).rstrip("\n"),
        "",
        'Cells: success (test episodes that ran, 95% Wilson interval); "paper" rows: Table 1 of '
        "the write-up this project started from (see [Citation](#citation); success %, 10 "
        "demonstrations, its number of test episodes not stated; `evaluation/paper.py`).",
    ]
    if count:
        lines += ["", "![results table as bars](results/table1.png)"]
    return "\n".join(lines) + "\n"


def replace_readme_block(text: str, block: str) -> str:
    """`text` with the part between README_START and README_END replaced by `block`."""
    start, end = text.find(README_START), text.find(README_END)
    if start < 0 or end < start:
        raise ValueError(
            f"the README has no results block: put the lines {README_START} and {README_END} "
            "where the table goes"
        )
    return text[: start + len(README_START)] + "\n" + block + text[end:]


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
    parser.add_argument(
        "--plot", type=Path, help="also draw the table as bars into this PNG (results/table1.png)"
    )
    parser.add_argument(
        "--readme",
        type=Path,
        help="also rewrite the results block of this README (between its two markers)",
    )
    args = parser.parse_args(argv)
    try:
        records = load_results([Path(root) for root in args.roots])
        if args.readme:
            text = args.readme.read_text()
            args.readme.write_text(replace_readme_block(text, readme_block(records)))
    except (OSError, ValueError) as error:
        print(f"nerf-transporter report: {error}", file=sys.stderr)
        return 1
    if not records:
        roots = " ".join(str(root) for root in args.roots)
        print(
            f"nerf-transporter report: no results under {roots} (only the paper's values below); "
            "run `nerf-transporter run-cell --task <task> --method <method>` or `lightning test "
            "--config <config> --ckpt_path <ckpt>` first",
            file=sys.stderr,
        )
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(args.plot), cv2.cvtColor(table_plot(records), cv2.COLOR_RGB2BGR)):
            print(f"nerf-transporter report: could not write {args.plot}", file=sys.stderr)
            return 1
    header, rows = results_table(records)
    sys.stdout.write(csv_text(header, rows) if args.csv else markdown(header, rows))
    return 0
