"""`nerf-transporter report results/ [--csv] [--plot PNG] [--readme README.md] [--results-doc
docs/results.md]`: the results table (docs/conventions.md, "Evaluation protocol").

Reads the records under the given directories (`experiments/cells.py`, which checks each): the
cells `run-cell` writes (`<root>/<column>/<row>.json`), or, in a folder without cells (`logs/`),
every `results*.json` (`lightning test`, one per tested checkpoint, anywhere below); a test record
under a folder of cells is left out, named on stderr. It prints one row per method (`mira` with
oracle imagery is a row of its own) and one column per task, setting tested in and setting trained
in: the eight of the table (each task trained Normal, tested Normal and Challenging), then any other
where records exist (place-red-in-green trained and tested Challenging, the optional ninth). A cell
reads "success / strict 6-DoF success", each "rate% (n, CI)" with the 95% Wilson interval in
percent ("-" for a record without the strict check), marked † where the cell read NeRF imagery
other than this code's default (`on_other_imagery`), and is empty where no run exists. Where
several records exist for one cell, a cell outranks a test record, then the newest wins. Below each
of our rows, the paper's Table 1 value of that method under the column its table labels it by
(`experiments/paper.py`; `PAPER_NOTE` on reading its caption). The cells of an earlier world,
kept under `<root>/archive/world-<fingerprint>/`, follow in a table of their own under the heading
"Archived world <fingerprint>", never in this world's table; so do this world's cells of an
earlier training recipe, kept under `<root>/archive/recipe-<name>/`, under "Earlier recipe <name>".
A table that mixes recipes (a row whose cells differ beyond their columns and their NeRF imagery,
or a column whose rows differ in budget or whose image rows differ in colour augmentation:
`mixed_recipes`) is printed still, and named on stderr.
`--plot` draws the table as bars with their intervals and the paper's values as markers;
`--validation-plots DIR` draws each column's validation success against training steps (the budget
study, `docs/budget.md`) and `--validation-tables` prints them. `--readme` rewrites the README's
results block (between `README_START` and `README_END`): the table with a pointer to the results
page. `--results-doc` rewrites that page's block (between `RESULTS_DOC_START` and
`RESULTS_DOC_END`): the table, the machine each cell's fit ran on, the paired comparisons of mira
with each other row, the run-cell command of each measured cell, and where the archived worlds lie.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from nerf_transporter.atomic import check_writable, write_text
from nerf_transporter.console import HelpFormatter
from nerf_transporter.data.observation import SceneSpec
from nerf_transporter.drawing import bar_chart, line_chart
from nerf_transporter.evaluation.metrics import cell, paired_comparison
from nerf_transporter.evaluation.view_search import VIEW_SEARCH_FIGURES, view_search_text
from nerf_transporter.experiments.cells import (
    ARCHIVE,
    Archive,
    column_folder,
    find_records,
    row_key,
    trained_setting,
)
from nerf_transporter.experiments.paper import PAPER_SUCCESS
from nerf_transporter.sim.fingerprint import world_fingerprint
from nerf_transporter.sim.registration import TASK_NAMES
from nerf_transporter.sim.tasks import SETTINGS

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
Column = tuple[str, str, str]  # (task, setting tested in, setting trained in)
# the table's columns, always shown: each task trained Normal, tested Normal and Challenging; other
# columns (a policy trained in another setting) follow where records exist
COLUMNS: tuple[Column, ...] = tuple(
    (task, setting, "normal") for task in TASK_NAMES for setting in ("normal", "challenging")
)
PAPER_NOTE = (
    "The paper's Table 1 labels four columns Normal and place-red-in-green Challenging, and its "
    'values stand under the columns of those labels. Its caption, though, reads "under '
    "out-of-distribution rotations\", and every result MIRA's code release shows is an "
    "out-of-distribution (`-ood`) run, so its Normal columns may be tests on Challenging poses: "
    "read them against both of ours."
)
README_START = "<!-- results table: written by `nerf-transporter report results/ --readme README.md`; do not edit -->"
README_END = "<!-- end of the results table -->"
RESULTS_DOC_START = (
    "<!-- results: written by `nerf-transporter report results/ --results-doc docs/results.md`; "
    "do not edit -->"
)
RESULTS_DOC_END = "<!-- end of the results -->"
# the results page, from the README; the README, from the results page
RESULTS_DOC_LINK, README_LINK = "docs/results.md", "../README.md"


def seed_outcomes(record: dict) -> dict[int, bool]:
    """A cell's test episodes, seed -> success, erred episodes left out."""
    return {e["seed"]: e["success"] for e in record["episode_results"] if not e.get("error")}


def column_name(task: str, setting: str, trained: str = "normal") -> str:
    """A column's header: the task, the setting tested in unless Normal, and the setting trained
    in unless Normal ("place-red-in-green Challenging (trained Challenging)")."""
    name = task if setting == "normal" else f"{task} {setting.capitalize()}"
    return name if trained == "normal" else f"{name} (trained {trained.capitalize()})"


def column_of(record: dict) -> Column:
    """The column of a record: (task, setting tested in, setting trained in)."""
    return record["task"], record["setting"], trained_setting(record)


def paper_value(method: str, column: Column) -> int | None:
    """The paper's Table 1 success % of a method under a column: where its table labels the
    column's task and setting (trained Normal, as its Challenging is defined), else None."""
    task, setting, trained = column
    return PAPER_SUCCESS.get(method, {}).get((task, setting)) if trained == "normal" else None


# the mark of a NeRF-imagery cell measured on imagery other than this code's default
OTHER_IMAGERY_MARK = "†"


def on_other_imagery(record: dict) -> bool:
    """Whether a cell of this world read NeRF imagery other than this code's default: its
    protocol's `imagery_changes` (none: the reference imagery) are not those of the default
    (`SceneSpec.imagery_changes`). False for other imagery, for a record without a protocol and for
    an archived world's cell (never compared with this code's)."""
    protocol = record.get("protocol") or {}
    if protocol.get("imagery") != "nerf" or record.get("world") != world_fingerprint():
        return False
    return protocol.get("imagery_changes", {}) != SceneSpec(protocol["task"]).imagery_changes()


def table_cell(record: dict) -> str:
    """A cell of the table: 'success / strict 6-DoF success', each as `cell` writes it ('-' for a
    record without the strict check), marked `OTHER_IMAGERY_MARK` where the cell read NeRF
    imagery other than the default (`on_other_imagery`)."""
    mark = f" {OTHER_IMAGERY_MARK}" if on_other_imagery(record) else ""
    strict = record.get("strict_successes")
    if strict is None:
        return f"{cell(record)} / -{mark}"
    figures = {"episodes": record["episodes"], "successes": strict}
    figures |= {"ci_low": record["strict_ci_low"], "ci_high": record["strict_ci_high"]}
    return f"{cell(record)} / {cell(figures)}{mark}"


def _rank(value: str, known: tuple[str, ...]) -> tuple[int, str]:
    return (known.index(value), "") if value in known else (len(known), value)


def _column_order(column: Column) -> tuple:
    """Sort key of a column: tasks, then settings trained in, then tested in, as listed."""
    return _rank(column[0], TASK_NAMES), _rank(column[2], SETTINGS), _rank(column[1], SETTINGS)


def cell_key(record: dict) -> tuple[str, str, str, str]:
    """(row, task, setting, trained setting): the table cell a record stands in (`row_key` names
    the row, `column_of` the rest)."""
    return (row_key(record["method"], record.get("imagery")), *column_of(record))


def newest_records(records: list[dict]) -> dict[tuple[str, str, str, str], dict]:
    """`cell_key` -> the newest record of that cell; a cell outranks any test record."""
    newest: dict[tuple[str, str, str, str], dict] = {}
    ranked = sorted(records, key=lambda r: ("protocol" in r, r.get("created", ""), r["path"]))
    for record in ranked:
        newest[cell_key(record)] = record
    return newest


# protocol keys that belong to a cell's column, or to the cell alone, not to its row's recipe: a
# NeRF cell's imagery is its own, marked in its cell where it is not the default (`table_cell`),
# since a changed default imagery re-measures a row's cells one fit at a time; the budget (steps)
# is the column's, as the paper's budgets are its tasks' (9000 to 40000 steps)
COLUMN_KEYS = (
    "task",
    "setting",
    "trained_setting",
    "fit_protocol_id",
    "colour_augment",
    "imagery_changes",
    "steps",
)
STATE_ROWS = ("gt_state_mlp",)  # rows that read no image: colour augmentation is no knob of theirs


def _differences(cells: dict[str, dict]) -> list[str]:
    """Each setting in which the named protocols `cells` disagree, as `<key>: <value> in <cell>,
    <cell>; <value> in <cell>` ("-" where a protocol has none)."""
    keys = sorted({key for protocol in cells.values() for key in protocol})
    texts = []
    for key in keys:
        by_value: dict[str, list[str]] = {}
        for name, protocol in cells.items():
            by_value.setdefault(json.dumps(protocol.get(key, "-")), []).append(name)
        if len(by_value) > 1:
            texts.append(
                f"{key}: " + "; ".join(f"{v} in {', '.join(n)}" for v, n in by_value.items())
            )
    return texts


def mixed_recipes(records: list[dict]) -> list[str]:
    """Where a table mixes recipes, one line each: a row whose cells differ in a setting that is
    not their column's (learning rate, architecture, training settings, view choice; not the NeRF
    imagery, marked cell by cell), or a column whose rows differ in budget (steps, every row) or
    whose image rows differ in colour augmentation. [] for a table of one recipe (an earlier
    recipe's cells belong under `<results>/archive/recipe-<name>/`)."""
    rows: dict[str, dict[str, dict]] = {}
    augments: dict[Column, dict[str, dict]] = {}
    budgets: dict[Column, dict[str, dict]] = {}
    for (row, *column), record in newest_records(records).items():
        protocol = record.get("protocol")
        if protocol is None:
            continue
        name = column_name(*column)
        rows.setdefault(row, {})[name] = {
            key: value for key, value in protocol.items() if key not in COLUMN_KEYS
        }
        method = METHODS.get(row, row)
        budgets.setdefault(tuple(column), {})[method] = {"steps": protocol.get("steps")}
        if row not in STATE_ROWS:
            augment = {"colour_augment": protocol.get("colour_augment", False)}
            augments.setdefault(tuple(column), {})[method] = augment
    lines = [
        f"row {METHODS.get(row, row)}: {text}"
        for row, cells in rows.items()
        for text in _differences(cells)
    ]
    lines += [
        f"column {column_name(*column)}: {text}"
        for by_column in (budgets, augments)
        for column, cells in by_column.items()
        for text in _differences(cells)
    ]
    return lines


def table_columns(newest: dict[tuple[str, str, str, str], dict]) -> list[Column]:
    """The table's columns: `COLUMNS`, then each other column that holds a record, in order."""
    extra = {key[1:] for key in newest} - set(COLUMNS)
    return list(COLUMNS) + sorted(extra, key=_column_order)


def table_rows(newest: dict[tuple[str, str, str, str], dict]) -> list[str]:
    """The table's rows: `METHODS`, then each other row that holds a record, by name."""
    return list(METHODS) + sorted({key[0] for key in newest} - set(METHODS))


def results_table(records: list[dict]) -> tuple[list[str], list[list[str]]]:
    """(header, rows): the newest record per (row, column) in its cell (`table_cell`); below each
    of our rows the paper's values of that method (`paper_value`; empty where it has none)."""
    newest = newest_records(records)
    columns = table_columns(newest)
    header = ["method"] + [column_name(*column) for column in columns]
    rows = []
    for method in table_rows(newest):
        cells = [
            table_cell(newest[(method, *column)]) if (method, *column) in newest else ""
            for column in columns
        ]
        rows.append([METHODS.get(method, method)] + cells)
        if method in PAPER_SUCCESS:
            paper = [paper_value(method, column) for column in columns]
            rows.append([PAPER_LABELS[method]] + ["" if v is None else f"{v}%" for v in paper])
    return header, rows


def measured_cells(records: list[dict]) -> int:
    """How many of the table's rows x columns (`COLUMNS`) hold a record."""
    newest = newest_records(records)
    return sum((row, *column) in newest for row in METHODS for column in COLUMNS)


def extra_column_counts(records: list[dict]) -> dict[Column, int]:
    """Columns beyond `COLUMNS` (a policy trained in another setting, e.g. the optional ninth
    column) -> how many of the table's rows hold a record there, in the table's column order."""
    counts = Counter(
        (task, setting, trained)
        for row, task, setting, trained in newest_records(records)
        if row in METHODS and (task, setting, trained) not in COLUMNS
    )
    return dict(sorted(counts.items(), key=lambda item: _column_order(item[0])))


def table_plot(records: list[dict]) -> np.ndarray:
    """The table as grouped bars (one group per column of `COLUMNS`, Normal and Challenging of
    each task side by side, then each column beyond them that holds a record, as
    `extra_column_counts` orders them; one bar per row) of the success with its 95% interval, and
    the paper's values (`paper_value`) as black diamonds; RGB uint8. Without records: the paper's
    values alone."""
    newest = newest_records(records)
    columns = list(COLUMNS) + list(extra_column_counts(records))
    shape = (len(METHODS), len(columns))
    values, low, high, paper = (np.full(shape, np.nan) for _ in range(4))
    for i, row in enumerate(METHODS):
        for j, column in enumerate(columns):
            record = newest.get((row, *column))
            if record is not None and record["episodes"]:
                values[i, j] = record["successes"] / record["episodes"]
                low[i, j], high[i, j] = record["ci_low"], record["ci_high"]
            if (value := paper_value(row, column)) is not None:
                paper[i, j] = value / 100
    table_cells = len(METHODS) * len(COLUMNS)
    return bar_chart(
        [column_name(*column).replace(" (", "\n(") for column in columns],
        list(METHODS.values()),
        values,
        low,
        high,
        paper,
        title=f"Success (the anchor's reward) with 95% Wilson interval, 10 demonstrations, "
        f"trained Normal unless labelled ({measured_cells(records)} of {table_cells} cells of "
        "the eight columns measured)",
        marker_label="paper (Table 1, under its labels)",
        size=(PLOT_HEIGHT, PLOT_MARGIN + PLOT_GROUP_WIDTH * len(columns)),
    )


# table1.png: its height, and its width as margins plus one group of six bars a column, labels apart
PLOT_HEIGHT, PLOT_MARGIN, PLOT_GROUP_WIDTH = 560, 80, 270
# the overlay that takes the reference imagery back (`data/observation.py`, REFERENCE_IMAGERY)
REFERENCE_IMAGERY_CONFIG = "configs/imagery/reference.yaml"
# run-cell's budget options and the protocol keys they set, in the order a command lists them
BUDGET_OPTIONS = (
    ("--steps", "steps"),
    ("--batch-size", "batch_size"),
    ("--lr", "lr"),
    ("--val-every", "validation_every"),
    ("--val-episodes", "validation_episodes"),
    ("--episodes", "test_episodes"),
)


def run_cell_command(record: dict) -> str:
    """The `nerf-transporter run-cell` command that measures a cell again: its protocol and the
    `--config` overlays it was run with; a NeRF-imagery cell of the reference imagery (no
    `imagery_changes`) with the overlay that takes it back (`REFERENCE_IMAGERY_CONFIG`) where this
    code's default imagery is another (`on_other_imagery`)."""
    protocol = record["protocol"]
    words = ["nerf-transporter run-cell", f"--task {protocol['task']}"]
    trained = protocol.get("trained_setting", protocol["setting"])
    if trained != "normal":
        words.append(f"--setting {trained}")
    if protocol["setting"] != trained:
        words.append(f"--test-setting {protocol['setting']}")
    words.append(f"--method {protocol['method']}")
    if protocol.get("imagery") == "oracle":
        words.append("--imagery oracle")
    words += [f"{option} {protocol[key]:g}" for option, key in BUDGET_OPTIONS]
    overlays = list(record.get("overlays", ()))
    if (
        on_other_imagery(record)
        and not protocol.get("imagery_changes")
        and REFERENCE_IMAGERY_CONFIG not in overlays
    ):
        overlays.append(REFERENCE_IMAGERY_CONFIG)
    words += [f"--config {overlay}" for overlay in overlays]
    return " ".join(words)


def in_table_order(records: list[dict]) -> list[tuple[str, dict]]:
    """(row, record) of each newest cell, by row as in the table, then column."""
    newest = newest_records(records)
    keys = sorted(newest, key=lambda key: (_rank(key[0], tuple(METHODS)), _column_order(key[1:])))
    return [(key[0], newest[key]) for key in keys]


def cell_commands(records: list[dict]) -> list[str]:
    """The run-cell command of each newest cell that holds its protocol, in table order."""
    return [
        run_cell_command(record)
        for _, record in in_table_order(records)
        if all(key in record.get("protocol", {}) for _, key in BUDGET_OPTIONS)
    ]


def validation_curves(records: list[dict]) -> dict[Column, list[tuple[str, dict]]]:
    """column -> (row, cell) of the newest cells of that column that hold their validation
    rounds, in table order."""
    curves: dict[Column, list[tuple[str, dict]]] = {}
    for row, record in in_table_order(records):
        if record.get("validation"):
            curves.setdefault(column_of(record), []).append((row, record))
    return curves


def validation_plot(column: Column, cells: list[tuple[str, dict]]) -> np.ndarray:
    """Closed-loop validation success against training steps, one line per (row, cell) of a
    column; RGB uint8."""
    episodes = {record.get("protocol", {}).get("validation_episodes") for _, record in cells}
    per_round = "/".join(str(n) for n in sorted(episodes - {None}))
    return line_chart(
        [METHODS.get(row, row) for row, _ in cells],
        [[entry["step"] for entry in record["validation"]] for _, record in cells],
        [[entry["success_rate"] for entry in record["validation"]] for _, record in cells],
        title=f"{column_name(*column)}: validation success ({per_round} episodes a round)",
        x_label="training step",
    )


def fit_machine_names(record: dict) -> list[str]:
    """The machines a cell's fit ran on, each named by its GPU, else its CPU."""
    fits = record.get("machine", {}).get("fit") or [{}]
    return sorted({fit.get("gpu") or fit.get("cpu") or "not recorded" for fit in fits})


def _round_text(ran: bool, rate: float | None, episodes: int | None) -> str:
    """A validation round as 'successes/episodes' ('-': no round at that step; 'erred')."""
    if not ran:
        return "-"
    if rate is None:
        return "erred"
    return f"{round(rate * episodes)}/{episodes}" if episodes else f"{rate:.0%}"


def validation_tables(records: list[dict]) -> str:
    """Markdown, one table per column: each newest cell's validation rounds (successes of the
    round's episodes, by step), its test, the chosen checkpoint's step and where it was fitted."""
    tables = []
    for column, cells in validation_curves(records).items():
        steps = sorted({entry["step"] for _, record in cells for entry in record["validation"]})
        header = [column_name(*column), *(f"step {step}" for step in steps)]
        rows = []
        for row, record in cells:
            episodes = record.get("protocol", {}).get("validation_episodes")
            rounds = {entry["step"]: entry["success_rate"] for entry in record["validation"]}
            rounds_text = [
                _round_text(step in rounds, rounds.get(step), episodes) for step in steps
            ]
            chosen = record.get("checkpoint", {}).get("step", "-")
            machines = ", ".join(fit_machine_names(record))
            rows.append([METHODS.get(row, row), *rounds_text, cell(record), str(chosen), machines])
        tables.append(markdown(header + ["test", "checkpoint step", "fitted on"], rows))
        searched = [(row, record) for row, record in cells if _view_rounds(record)]
        if searched:  # mira: the view search of the same rounds, and of the test
            view_rows = [
                [
                    METHODS.get(row, row),
                    *(view_search_text(_view_rounds(record).get(step)) for step in steps),
                    view_search_text(record.get("view_search")),
                ]
                for row, record in searched
            ]
            view_header = [f"{column_name(*column)}: view search", *header[1:], "test"]
            tables.append(markdown(view_header, view_rows))
    return "\n".join(tables)


def _view_rounds(record: dict) -> dict[int, dict]:
    """step -> the view-search figures of a cell's validation rounds that hold them."""
    return {
        entry["step"]: entry
        for entry in record.get("validation", [])
        if all(name in entry for name in VIEW_SEARCH_FIGURES)
    }


def fit_machines(records: list[dict]) -> list[str]:
    """One line per machine the newest cells' fits ran on (its GPU, else its CPU): how many cells
    and which, by row then column as in the table."""
    cells: dict[str, dict[str, list[str]]] = {}
    for row, record in in_table_order(records):
        for name in fit_machine_names(record):
            column = column_name(*column_of(record))
            cells.setdefault(name, {}).setdefault(METHODS.get(row, row), []).append(column)
    lines = []
    for name, rows in cells.items():
        count = sum(map(len, rows.values()))
        listed = "; ".join(f"{row} on {', '.join(columns)}" for row, columns in rows.items())
        lines.append(f"{name} ({count} cell{'' if count == 1 else 's'}): {listed}")
    return lines


def _machine_lines(records: list[dict]) -> list[str]:
    """The README's lines on where the cells' fits ran, none where no cell says."""
    machines = fit_machines(records)
    if not machines:
        return []
    where = "Where the fits ran (each cell's `machine.fit`; its test ran on `machine.test`):"
    return ["", where, "", *(f"- {line}" for line in machines)]


def _paired_text(ours: dict | None, other: dict | None) -> str:
    """'mira only / the other only, p <exact McNemar p>' of two cells on their common test seeds;
    empty where either is missing, holds no episodes, or they share no seed."""
    if any(record is None or "episode_results" not in record for record in (ours, other)):
        return ""
    first, second = seed_outcomes(ours), seed_outcomes(other)
    if not set(first) & set(second):
        return ""
    paired = paired_comparison(first, second)
    return f"{paired['first_only']} / {paired['second_only']}, p {paired['p_value']:.2g}"


def paired_comparisons(records: list[dict]) -> tuple[list[str], list[list[str]]]:
    """(header, rows): mira (ours) against each other row, column by column, paired on their
    common test seeds (`_paired_text`), as `compare-cells` pairs two cells."""
    newest = newest_records(records)
    columns = table_columns(newest)
    header = [f"{METHODS['mira']} against"] + [column_name(*column) for column in columns]
    rows = [
        [METHODS.get(row, row)]
        + [
            _paired_text(newest.get(("mira", *column)), newest.get((row, *column)))
            for column in columns
        ]
        for row in table_rows(newest)
        if row != "mira"
    ]
    return header, rows


def archive_title(archive: Archive) -> str:
    """The heading line of an archived world's or recipe's table in the report's output."""
    cells = len(newest_records(archive.cells))
    if archive.recipe is not None:
        return (
            f"Earlier recipe {archive.recipe} ({archive.folder}: {cells} cells of this world, "
            "measured under a training recipe the table has left)"
        )
    return (
        f"Archived world {archive.world} ({archive.folder}: {cells} "
        "cells, measured in an earlier world, not comparable with this world's)"
    )


def _measured_line(records: list[dict]) -> str:
    """The line that opens both results blocks: how many cells are measured, in which world, and
    the columns beyond the eight."""
    count, total = measured_cells(records), len(METHODS) * len(COLUMNS)
    world = f"this checkout's world `{world_fingerprint()}` (its fingerprint, `sim/fingerprint.py`)"
    beyond = "".join(
        f" Beyond the {len(COLUMNS)} columns: {column_name(*column)}, {cells} of "
        f"{len(METHODS)} cells."
        for column, cells in extra_column_counts(records).items()
    )
    measured = (
        f"{count} of {total} cells measured in `results/`, in {world}."
        if count
        else f"no cell has been measured yet in {world}: `results/` holds none of the {total}, "
        "the table shows the paper's values only."
    )
    return f"Full protocol (`nerf-transporter run-cell`): {measured}{beyond}"


def _legend(citation: str, records: list[dict]) -> str:
    """How to read the table's columns, cells (and the mark of a cell on other NeRF imagery, where
    one is) and paper rows; `citation` links the paper."""
    marked = any(on_other_imagery(record) for record in newest_records(records).values())
    other_imagery = (
        f"{OTHER_IMAGERY_MARK}: a NeRF-imagery cell measured on imagery other than this code's "
        "default; a cell fitted before the default changed read the reference imagery "
        '(`configs/imagery/reference.yaml`; docs/imagery.md, "The default imagery"), and each '
        "cell's command names the overlay that takes its imagery back. "
        if marked
        else ""
    )
    return (
        "Columns: each task trained on Normal demonstrations and tested on Normal and on "
        "Challenging test seeds (the same checkpoint, chosen on Normal validation seeds); a "
        "column trained and tested Challenging (`--setting challenging`) follows where its cells "
        "exist. Cells: success (the anchor's reward) / strict success (the 6-DoF check; - where "
        "the cell lacks it), each rate% (test episodes that ran, 95% Wilson interval). "
        f'{other_imagery}"paper" '
        f"rows: Table 1 of the write-up this project started from (see [Citation]({citation}); "
        "success %, 10 demonstrations, its number of test episodes not stated; "
        "`experiments/paper.py`)."
    )


def readme_block(records: list[dict]) -> str:
    """The README's results block (without its markers): this world's table with its world, how
    many cells are measured, the plot, and where the rest lies (`results_doc_block`)."""
    lines = [_measured_line(records), "", markdown(*results_table(records)).rstrip("\n")]
    lines += ["", _legend("#citation", records)]
    if measured_cells(records):
        lines += ["", "![results table as bars](results/table1.png)"]
    lines += [
        "",
        "Where each cell was fitted, the paired comparisons, the command that measures each cell "
        f"again, and any archived world's cells: [{RESULTS_DOC_LINK}]({RESULTS_DOC_LINK}).",
    ]
    return "\n".join(lines) + "\n"


def results_doc_block(records: list[dict], archives: Sequence[Archive] = ()) -> str:
    """The results page's block (without its markers): this world's table with its world, how
    many cells are measured, how to read it, where they were fitted, the plot, the paired
    comparisons and the run-cell commands; then where each archived world's cells lie."""
    lines = [_measured_line(records), "", markdown(*results_table(records)).rstrip("\n")]
    lines += [
        "",
        f"{_legend(README_LINK + '#citation', records)} {PAPER_NOTE}",
        *_machine_lines(records),
    ]
    if measured_cells(records):
        lines += ["", "![results table as bars](../results/table1.png)"]
    header, rows = paired_comparisons(records)
    if any(any(row[1:]) for row in rows):
        lines += [
            "",
            "Paired comparisons: mira (ours) against each other row of a column on their common "
            "test seeds (`nerf-transporter compare-cells`): the seeds only mira succeeded on / "
            "only the other row did, and the exact McNemar p (two rates of 100 episodes differ by "
            "chance by up to ~13 points; on the same seeds only these seeds decide).",
            "",
            markdown(header, rows).rstrip("\n"),
        ]
    commands = cell_commands(records)
    if commands:
        lines += [
            "",
            "Each measured cell is measured again from scratch by (its protocol, as recorded):",
        ]
        lines += ["", *(f"    {command} --force" for command in commands)]
    for archive in archives:
        cells = len(newest_records(archive.cells))
        if archive.recipe is not None:
            text = (
                f"Earlier recipe `{archive.recipe}`: {cells} cells of this world, kept in "
                f"`results/{ARCHIVE}/recipe-{archive.recipe}/`: the same seeds and world, fitted "
                "under the training recipe the table used before (what changed: "
                "[budget.md](budget.md)). "
            )
        else:
            text = (
                f"Archived world `{archive.world}`: {cells} cells, kept "
                f"in `results/{ARCHIVE}/world-{archive.world}/`; its seeds built other scenes than "
                "this world's, so these numbers are not comparable with the table above. "
            )
        lines += [
            "",
            text + "`nerf-transporter report results/` prints its table after this world's.",
        ]
    return "\n".join(lines) + "\n"


def replace_block(text: str, block: str, start_marker: str, end_marker: str) -> str:
    """`text` with the part between the two markers replaced by `block`."""
    start, end = text.find(start_marker), text.find(end_marker)
    if start < 0 or end < start:
        raise ValueError(
            f"no results block: put the lines {start_marker} and {end_marker} where it goes"
        )
    return text[: start + len(start_marker)] + "\n" + block + text[end:]


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


def _write_png(path: Path, image: np.ndarray) -> bool:
    """Write an RGB image; False, with the reason printed, where it cannot be written."""
    if cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        return True
    print(f"nerf-transporter report: could not write {path}", file=sys.stderr)
    return False


def _rewritten(path: Path, block: str, start_marker: str, end_marker: str) -> str:
    """The text of `path` with its block between the two markers replaced by `block`; a
    ValueError naming the file where it lacks them."""
    try:
        return replace_block(path.read_text(), block, start_marker, end_marker)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def _rewrites(
    args: argparse.Namespace, records: list[dict], archives: Sequence[Archive]
) -> dict[Path, str]:
    """path -> its new text, for the README (`--readme`) and the results page (`--results-doc`)
    asked for; both are read and checked for their markers before either is written."""
    rewrites = {}
    if args.readme:
        block = readme_block(records)
        rewrites[args.readme] = _rewritten(args.readme, block, README_START, README_END)
    if args.results_doc:
        block = results_doc_block(records, archives)
        rewrites[args.results_doc] = _rewritten(
            args.results_doc, block, RESULTS_DOC_START, RESULTS_DOC_END
        )
    return rewrites


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter report",
        description="Print the success-rate table (rate% (episodes, 95% Wilson CI)) from the "
        "cells run-cell wrote (<folder>/<column>/<row>.json), or from the results files "
        "(results*.json) `lightning test` wrote, under the given directories; the cells of an "
        "earlier world (<folder>/archive/world-<fingerprint>/) follow in tables of their own.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "roots", nargs="*", default=["logs"], help="folders of cells (results/) or of runs (logs/)"
    )
    parser.add_argument("--csv", action="store_true", help="CSV instead of a markdown table")
    parser.add_argument(
        "--plot", type=Path, help="also draw the table as bars into this PNG (results/table1.png)"
    )
    parser.add_argument(
        "--validation-plots",
        type=Path,
        help="also draw each column's validation success against steps into "
        "<this folder>/validation-<column>.png (docs/)",
    )
    parser.add_argument(
        "--readme",
        type=Path,
        help="also rewrite the results block of this README (between its two markers): the table",
    )
    parser.add_argument(
        "--results-doc",
        type=Path,
        help="also rewrite the results block of this page (docs/results.md, between its two "
        "markers): the table, the machines, the paired comparisons, every cell's run-cell command",
    )
    parser.add_argument(
        "--validation-tables",
        action="store_true",
        help="print, after the table, each column's validation rounds per cell (docs/budget.md)",
    )
    args = parser.parse_args(argv)
    try:
        if args.plot:
            check_writable("--plot", args.plot, file=True)
        found = find_records([Path(root) for root in args.roots])
        records = found.records
        rewrites = _rewrites(args, records, found.archives)
        for path, text in rewrites.items():
            write_text(path, text)
    except (OSError, ValueError) as error:
        print(f"nerf-transporter report: {error}", file=sys.stderr)
        return 2
    if found.left_out:
        print(
            f"nerf-transporter report: left out {len(found.left_out)} test record(s) under a "
            "folder of cells (not cells of the table): "
            + ", ".join(str(path) for path in found.left_out),
            file=sys.stderr,
        )
    if mixed := mixed_recipes(records):
        print(
            "nerf-transporter report: the table mixes recipes (one recipe a row; an earlier "
            "recipe's cells go to <results>/archive/recipe-<name>/, docs/results.md):\n  "
            + "\n  ".join(mixed),
            file=sys.stderr,
        )
    if not records:
        roots = " ".join(str(root) for root in args.roots)
        print(
            f"nerf-transporter report: no results of this checkout's world {world_fingerprint()} "
            f"under {roots} (only the paper's values below); run `nerf-transporter run-cell "
            "--task <task> --method <method>` or `lightning test --config <config> --ckpt_path "
            "<ckpt>` first",
            file=sys.stderr,
        )
    if args.plot:
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        if not _write_png(args.plot, table_plot(records)):
            return 1
    if args.validation_plots:
        args.validation_plots.mkdir(parents=True, exist_ok=True)
        for column, cells in validation_curves(records).items():
            path = args.validation_plots / f"validation-{column_folder(*column)}.png"
            if not _write_png(path, validation_plot(column, cells)):
                return 1
    table = csv_text if args.csv else markdown
    sys.stdout.write(table(*results_table(records)))
    for archive in found.archives:
        title = (
            csv_text([archive_title(archive)], []) if args.csv else f"{archive_title(archive)}\n\n"
        )
        sys.stdout.write("\n" + title + table(*results_table(archive.cells)))
    if args.validation_tables:
        sys.stdout.write("\n" + validation_tables(records))
        for archive in found.archives:
            if tables := validation_tables(archive.cells):
                sys.stdout.write(f"\n{archive_title(archive)}\n\n{tables}")
    return 0
