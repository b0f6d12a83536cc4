"""`nerf-transporter failures results/ [CELL.json ...]`: why the test episodes of the results table's cells failed.

Each test episode of a cell (`run-cell`'s JSON records every episode's action) is replayed up to
its action: the seed's scene is reset, no policy and no imagery, and the recorded action is judged
before the robot moves. A failed episode falls in one class:

- `picked another body`: the top-down pixel under the pick shows something other than the object
  (the fixture, a distractor, the table), which the suction meets first on its way down;
- `aimed off`: the object, carried rigidly from the pick pose to the place pose
  (`carried_pose`: place . inv(pick) . object, the inverse of the oracle's place), misses every
  target under the task's tolerance (`MatchTolerance`, the anchor's check, docs/conventions.md). The position error is
  taken across the place's approach axis, since the place motion descends along that axis until
  the object touches something (an error along it does not count). `missed` says which of
  position, tilt and yaw were out of tolerance (an episode can miss several);
- `aimed within tolerance`: the aim was right and the object did not settle there (it slid,
  bounced or tipped on release); those whose object ended more than 5 cm from the target (the
  cell's recorded pose error) left the target altogether;
- the rollout's own reason where the robot failed in motion (a pose unreachable, a timeout, a pick
  that touched nothing).

Apart from its class, a failure whose pick lies on the empty table (the top-down pixel under the
pick shows the table) is counted, and among them those on a corner pixel of the image (`picks on
the empty table (on the image's corner)`): a learnt pick that found no object it scored above the
table, whatever its class then (docs/failures.md, "Picks on the image's corner").
Erred episodes (not counted in a cell's rate) are counted apart. Successes whose aim was off count
too: how often the world forgives an aim (block-insertion's flat placements, docs/six_dof.md).
A second table gives success against the tilt of the target aimed at (its normal from the
vertical), a third against the aim's tilt error (the carried object's tilt against its target's,
for the episodes that picked the object: where a check free of tilt still fails on a tilted
release, as place-red-in-green's steep bowls do); mira's view search follows, and a last table
pairs mira with every other row of its column on the same test seeds (both, only one, neither
succeeded, and the exact McNemar p-value), e.g. mira with NeRF against mira with oracle imagery:
the NeRF-vs-oracle gap.
A test record given as a file (`evaluate-checkpoints --split test`, `lightning test`: a checkpoint
tested outside the table, e.g. on the other imagery) is analysed too, after the cells, named by its
file and left out of the pairs (`compare-cells` pairs it).
The scenes are this checkout's: a cell measured in another world (its `world` fingerprint) is
refused, since its seeds would build other scenes here.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from collections import Counter
from collections.abc import Mapping
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.atomic import check_writable, write_json
from nerf_transporter.console import HelpFormatter, progress_bar
from nerf_transporter.evaluation.metrics import paired_comparison
from nerf_transporter.evaluation.rollout import NOT_ACHIEVED
from nerf_transporter.evaluation.view_search import summary as view_search_summary
from nerf_transporter.evaluation.view_search import view_search_text
from nerf_transporter.experiments.cells import find_records, load_record, row_key, trained_setting
from nerf_transporter.experiments.report import (
    METHODS,
    cell_key,
    column_name,
    column_of,
    in_table_order,
    markdown,
    seed_outcomes,
)
from nerf_transporter.geometry import Pose
from nerf_transporter.sim import make_env
from nerf_transporter.sim.env import RavensEnv
from nerf_transporter.sim.fingerprint import world_fingerprint
from nerf_transporter.sim.tasks import Task

PICKED_ANOTHER_BODY = "picked another body"
AIMED_OFF = "aimed off"
AIMED_WITHIN_TOLERANCE = "aimed within tolerance"
POSE_PARTS = ("position", "tilt", "yaw")
ENDED_AWAY_M = 0.05  # a failure whose object ended farther than this from its target left it
TILT_BINS_DEG = (0, 10, 20, 30, 90)  # target tilt bins of the success-by-tilt table
# bins of the aim's tilt error (the carried object's against its target's) of the success-by-aim
# table: where the place's tilt, not its position, decides (place-red-in-green's steep bowls)
TILT_ERROR_BINS_DEG = (0, 5, 10, 15, 20, 30, 180)


class FailureAnalysisError(ValueError):
    """A cell that cannot be replayed here (no recorded actions, another world)."""


def carried_pose(object_pose: Pose, action: Mapping[str, Pose]) -> Pose:
    """Where `action` puts an object at `object_pose` if the suction holds it rigidly from the pick
    pose to the place pose: place . inv(pick) . object."""
    return geometry.multiply_poses(
        action["place"], geometry.invert_pose(action["pick"]), object_pose
    )


def aim(task: Task, object_pose: Pose, action: Mapping[str, Pose]) -> dict[str, Any]:
    """The carried object against the target it comes closest to matching: `missed` (the parts
    out of tolerance, position taken across the place's approach axis), the errors (m, rad) and
    `target_index`."""
    carried = carried_pose(object_pose, action)
    approach = geometry.quat_to_matrix(action["place"][1])[:, 2]
    tolerance = task.tolerance
    limits = {"position": tolerance.position, "tilt": tolerance.roll_pitch, "yaw": tolerance.yaw}
    aims = []
    for index, target in enumerate(task.target_poses):
        check = tolerance.check(carried, target)
        offset = np.asarray(carried[0]) - np.asarray(target[0])
        across = float(np.linalg.norm(offset - (offset @ approach) * approach))
        errors = {"position": across, "tilt": check["tilt_error"], "yaw": check["yaw_error"]}
        missed = [
            part for part in POSE_PARTS if limits[part] is not None and errors[part] > limits[part]
        ]
        aims.append({"missed": missed, "errors": errors, "target_index": index})
    return min(aims, key=lambda a: (bool(a["missed"]), a["errors"]["position"]))


def _pose(values: list[float]) -> Pose:
    return np.asarray(values[:3], dtype=float), np.asarray(values[3:], dtype=float)


def classify(episode: Mapping[str, Any], picked_object: bool | None, aimed: dict | None) -> str:
    """The class of one recorded episode (see the module docstring); `picked_object` and `aimed`
    come from the replayed scene (None where the episode has no action)."""
    if episode.get("error"):
        return "erred"
    if episode["success"]:
        return "success"
    if episode["failure"] != NOT_ACHIEVED:
        return str(episode["failure"]).split(" (")[0]
    if picked_object is False:
        return PICKED_ANOTHER_BODY
    if aimed is not None and aimed["missed"]:
        return AIMED_OFF
    return AIMED_WITHIN_TOLERANCE


def on_image_corner(pixel: tuple[int, int], shape: tuple[int, int]) -> bool:
    """Whether a (row, col) pixel is one of the four corner pixels of an image of `shape`."""
    row, col = pixel
    return row in (0, shape[0] - 1) and col in (0, shape[1] - 1)


def pick_pixel(position: np.ndarray) -> tuple[int, int]:
    """The top-down (row, col) pixel under a world position (x, y[, z])."""
    row, col = np.round(geometry.world_to_pixel(position)).astype(int)
    return int(row), int(col)


def body_at(ids: np.ndarray, pixel: tuple[int, int]) -> int | None:
    """The body id a top-down segmentation shows at a pixel; None outside the image."""
    return int(ids[pixel]) if geometry.pixel_inside_image(pixel, ids.shape) else None


def diagnose_episode(env: RavensEnv, episode: Mapping[str, Any]) -> dict[str, Any]:
    """One recorded episode replayed in `env` (of its task and setting) up to its action."""
    picked_object, aimed, target_tilt, corner, on_table = None, None, None, False, False
    if episode.get("action"):
        action = {key: _pose(values) for key, values in episode["action"].items()}
        env.reset(seed=episode["seed"])
        ids, _ = env.render_segmentation_top_down()
        pixel = pick_pixel(action["pick"][0])
        corner = on_image_corner(pixel, ids.shape)
        body = body_at(ids, pixel)
        picked_object = body == env.task.object_id
        on_table = body == env.table_id
        aimed = aim(env.task, env.task.object_pose(env), action)
        target = env.task.target_poses[aimed["target_index"]]
        normal_z = geometry.quat_to_matrix(target[1])[2, 2]
        target_tilt = float(np.degrees(np.arccos(np.clip(normal_z, -1.0, 1.0))))
    return {
        "seed": episode["seed"],
        "class": classify(episode, picked_object, aimed),
        "picked_object": picked_object,
        "pick_on_image_corner": corner,
        "pick_on_empty_table": on_table,
        "aim": aimed,
        "target_tilt_deg": target_tilt,
        "ended_position_error": (episode.get("pose_error") or {}).get("position_error"),
    }


def _is_pose(values: Any) -> bool:
    """Whether `values` is a recorded pose: 7 finite numbers (position, quaternion)."""
    return (
        isinstance(values, list)
        and len(values) == 7
        and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in values
        )
    )


def check_replayable(record: Mapping[str, Any]) -> None:
    """FailureAnalysisError naming the file and the episode where an episode cannot be classed: a
    failure (neither success nor error) without its reason (`failure`), or an action that is not
    {"pick": pose, "place": pose}, each pose 7 finite numbers (position, quaternion)."""
    for index, episode in enumerate(record.get("episode_results") or []):
        where = f"{record.get('path')}: episode_results[{index}] (seed {episode.get('seed')})"
        failed = episode.get("error") is None and not episode.get("success")
        if failed and not isinstance(episode.get("failure"), str):
            raise FailureAnalysisError(
                f"{where} failed without its reason: failure is "
                f"{json.dumps(episode.get('failure'))}, not a string"
            )
        action = episode.get("action")
        if action and not (
            isinstance(action, Mapping)
            and set(action) == {"pick", "place"}
            and all(_is_pose(pose) for pose in action.values())
        ):
            raise FailureAnalysisError(
                f'{where}: action is {json.dumps(action)[:60]}, not {{"pick": pose, '
                '"place": pose}, each pose 7 numbers (position, quaternion)'
            )


def diagnose_cell(record: Mapping[str, Any], progress: bool = True) -> list[dict[str, Any]]:
    """Every test episode of a cell, replayed to its action: seed, class, whether the pick pixel
    shows the object, and the aim (`aim`); episodes without an action get only their class."""
    episodes = record.get("episode_results")
    if not episodes:
        raise FailureAnalysisError(
            f"{record.get('path')}: no episode results (run-cell's cells and the test records "
            "of evaluate-checkpoints and lightning test hold them)"
        )
    if record.get("world") != world_fingerprint():
        raise FailureAnalysisError(
            f"{record.get('path')} was measured in world {record.get('world')}, this checkout's "
            f"is {world_fingerprint()}: its seeds build other scenes here; analyse it at the "
            f"commit it was measured at ({(record.get('git') or {}).get('commit')})"
        )
    env = make_env(record["task"], record["setting"])
    label = (
        f"{record['task']} {record['setting']} {row_key(record['method'], record.get('imagery'))}"
    )
    diagnoses = []
    try:
        with progress_bar(len(episodes), label, enabled=progress) as bar:
            for episode in episodes:
                diagnoses.append(diagnose_episode(env, episode))
                bar.update()
    finally:
        env.close()
    return diagnoses


AIM_UNITS = (
    ("position", 1000.0, "mm"),
    ("tilt", 180.0 / np.pi, "deg"),
    ("yaw", 180.0 / np.pi, "deg"),
)


def median_aim_errors(diagnoses: list[dict[str, Any]]) -> dict[str, float | None]:
    """Median aim error per part over the diagnoses with an aim, in mm and degrees."""
    aimed = [d["aim"]["errors"] for d in diagnoses if d["aim"] is not None]
    return {
        f"{part}_{unit}": statistics.median(e[part] * scale for e in aimed) if aimed else None
        for part, scale, unit in AIM_UNITS
    }


def median_target_tilt(diagnoses: list[dict[str, Any]]) -> float | None:
    """Median tilt (deg, normal from the vertical) of the targets the diagnoses aimed at."""
    tilts = [d["target_tilt_deg"] for d in diagnoses if d["target_tilt_deg"] is not None]
    return statistics.median(tilts) if tilts else None


def summary(record: Mapping[str, Any], diagnoses: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts per class, the failures aimed off per missed part, successes aimed off, and the
    median aim errors of successes and of failures (mm, deg)."""
    classes = Counter(d["class"] for d in diagnoses)
    successes = [d for d in diagnoses if d["class"] == "success"]
    failures = [d for d in diagnoses if d["class"] not in ("success", "erred")]
    missed = Counter(
        part for d in failures if d["class"] == AIMED_OFF for part in d["aim"]["missed"]
    )
    return {
        "path": record.get("path"),
        "task": record["task"],
        "setting": record["setting"],
        "trained_setting": trained_setting(record),
        "row": row_key(record["method"], record.get("imagery")),
        "test_record": None if "protocol" in record else Path(record["path"]).name,
        "episodes": len(diagnoses),
        "classes": dict(classes),
        "aimed_off_missed": {part: missed[part] for part in POSE_PARTS},
        "successes_aimed_off": sum(1 for d in successes if d["aim"] and d["aim"]["missed"]),
        "failed_picks_on_empty_table": sum(1 for d in failures if d["pick_on_empty_table"]),
        "failed_picks_on_image_corner": sum(1 for d in failures if d["pick_on_image_corner"]),
        "median_aim_error": {
            "successes": median_aim_errors(successes),
            "failures": median_aim_errors(failures),
        },
        "aimed_within_tolerance_ended_away": sum(
            1
            for d in failures
            if d["class"] == AIMED_WITHIN_TOLERANCE
            and (d["ended_position_error"] or 0.0) > ENDED_AWAY_M
        ),
        "median_target_tilt_deg": {
            "successes": median_target_tilt(successes),
            "failures": median_target_tilt(failures),
        },
        "success_by_target_tilt": success_by_target_tilt(diagnoses),
        "success_by_aim_tilt_error": success_by_aim_tilt_error(diagnoses),
        "view_search": view_search_by_outcome(record),
    }


def view_search_by_outcome(record: Mapping[str, Any]) -> dict[str, Any] | None:
    """mira: the view search's figures (`view_search.summary`) and the median pixel error in the
    true view, over the successes and over the failures; None where no episode records it."""
    ran = [e for e in record.get("episode_results", []) if e.get("error") is None]
    if not any(e.get("view_search") for e in ran):
        return None
    by_outcome = {}
    for name, wanted in (("successes", True), ("failures", False)):
        searched = [e["view_search"] for e in ran if bool(e["success"]) == wanted]
        errors = [
            s["true_view_pixel_error"]
            for s in searched
            if s and s.get("true_view_pixel_error") is not None
        ]
        by_outcome[name] = (view_search_summary(searched) or {}) | {
            "median_true_view_pixel_error": float(np.median(errors)) if errors else None
        }
    return by_outcome


def view_search_table(summaries: list[dict[str, Any]]) -> tuple[list[str], list[list[str]]] | None:
    """mira's cells: where the view search placed against the true view, successes / failures."""
    searched = [entry for entry in summaries if entry.get("view_search")]
    if not searched:
        return None
    header = [
        "column",
        "method",
        "view search, successes",
        "view search, failures",
        "median pixel error in the true view, successes / failures",
    ]
    rows = []
    for entry in searched:
        outcomes = entry["view_search"]
        pixels = [
            outcomes[name]["median_true_view_pixel_error"] for name in ("successes", "failures")
        ]
        rows.append(
            [
                column_name(entry["task"], entry["setting"], entry["trained_setting"]),
                _row_label(entry),
                view_search_text(outcomes["successes"]),
                view_search_text(outcomes["failures"]),
                " / ".join("-" if value is None else f"{value:.1f}" for value in pixels),
            ]
        )
    return header, rows


def _success_by_bin(
    diagnoses: list[dict[str, Any]], values: list[float | None], bins: tuple[int, ...]
) -> dict[str, list[int]]:
    """'<low>-<high>' -> [successes, episodes] of the diagnoses whose value (None: not counted)
    falls in that bin."""
    counted = [(d, v) for d, v in zip(diagnoses, values, strict=True) if v is not None]
    return {
        f"{low}-{high}": [
            sum(d["class"] == "success" for d, v in counted if low <= v < high),
            sum(1 for _, v in counted if low <= v < high),
        ]
        for low, high in pairwise(bins)
    }


def success_by_target_tilt(diagnoses: list[dict[str, Any]]) -> dict[str, list[int]]:
    """'<low>-<high>' deg (`TILT_BINS_DEG`) -> [successes, episodes] of the counted episodes whose
    target tilt falls in that bin."""
    tilts = [None if d["class"] == "erred" else d["target_tilt_deg"] for d in diagnoses]
    return _success_by_bin(diagnoses, tilts, TILT_BINS_DEG)


def success_by_aim_tilt_error(diagnoses: list[dict[str, Any]]) -> dict[str, list[int]]:
    """'<low>-<high>' deg (`TILT_ERROR_BINS_DEG`) -> [successes, episodes] of the episodes that
    picked the object, by their aim's tilt error (erred ones and picks of another body apart)."""
    errors = [
        math.degrees(d["aim"]["errors"]["tilt"])
        if d["class"] != "erred" and d["picked_object"] and d["aim"] is not None
        else None
        for d in diagnoses
    ]
    return _success_by_bin(diagnoses, errors, TILT_ERROR_BINS_DEG)


def _row_label(entry: dict[str, Any]) -> str:
    """The table's name of a summary's row; a test record's names its file too."""
    name = METHODS.get(entry["row"], entry["row"])
    return f"{name} ({entry['test_record']})" if entry.get("test_record") else name


def _numbers_text(medians: dict[str, float | None]) -> str:
    return " / ".join("-" if value is None else f"{value:.0f}" for value in medians.values())


def summary_table(summaries: list[dict[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """One row per cell: episodes, successes (aimed off among them), the failure classes, the
    median aim errors."""
    header = [
        "column",
        "method",
        "episodes",
        "successes (aimed off)",
        "picked another body",
        "aimed off: position / tilt / yaw missed",
        "aimed within tolerance (ended > 5 cm away)",
        "failed in motion",
        "picks on the empty table (on the image's corner)",
        "erred",
        "median aim error, successes (mm / deg / deg)",
        "median aim error, failures",
        "median target tilt, successes / failures (deg)",
    ]
    known = {"success", "erred", PICKED_ANOTHER_BODY, AIMED_OFF, AIMED_WITHIN_TOLERANCE}
    rows = []
    for entry in summaries:
        classes, missed = entry["classes"], entry["aimed_off_missed"]
        motion = {name: count for name, count in classes.items() if name not in known}
        motion_text = "; ".join(f"{count} {name}" for name, count in sorted(motion.items()))
        rows.append(
            [
                column_name(entry["task"], entry["setting"], entry["trained_setting"]),
                _row_label(entry),
                str(entry["episodes"]),
                f"{classes.get('success', 0)} ({entry['successes_aimed_off']})",
                str(classes.get(PICKED_ANOTHER_BODY, 0)),
                f"{classes.get(AIMED_OFF, 0)}: "
                + " / ".join(str(missed[part]) for part in POSE_PARTS),
                f"{classes.get(AIMED_WITHIN_TOLERANCE, 0)} "
                f"({entry['aimed_within_tolerance_ended_away']})",
                motion_text or "0",
                f"{entry['failed_picks_on_empty_table']} ({entry['failed_picks_on_image_corner']})",
                str(classes.get("erred", 0)),
                _numbers_text(entry["median_aim_error"]["successes"]),
                _numbers_text(entry["median_aim_error"]["failures"]),
                _numbers_text(entry["median_target_tilt_deg"]),
            ]
        )
    return header, rows


def binned_table(
    summaries: list[dict[str, Any]], key: str, bins: tuple[int, ...], label: str
) -> tuple[list[str], list[list[str]]]:
    """One row per cell: successes / episodes per bin of the summaries' `key` entry."""
    names = [f"{low}-{high}" for low, high in pairwise(bins)]
    header = ["column", "method", *(f"{label} {name} deg" for name in names)]
    rows = [
        [
            column_name(entry["task"], entry["setting"], entry["trained_setting"]),
            _row_label(entry),
            *("{}/{}".format(*entry[key][name]) for name in names),
        ]
        for entry in summaries
    ]
    return header, rows


PAIRED_COUNTS = ("seeds", "both", "first_only", "second_only", "neither")


def paired_table(records: list[dict[str, Any]]) -> tuple[list[str], list[list[str]]]:
    """mira against every other row of its column on their common test seeds (erred episodes
    left out): seeds both, only mira, only the other, neither succeeded on, exact McNemar p."""
    header = ["column", "mira against", "seeds", "both", "mira only", "other only", "neither", "p"]
    outcomes = {
        (*column_of(r), row_key(r["method"], r.get("imagery"))): seed_outcomes(r) for r in records
    }
    rows = []
    for (*column, row), other in outcomes.items():
        mira = outcomes.get((*column, "mira"))
        if row == "mira" or mira is None:
            continue
        paired = paired_comparison(mira, other)
        rows.append(
            [
                column_name(*column),
                METHODS.get(row, row),
                *(str(paired[key]) for key in PAIRED_COUNTS),
                f"{paired['p_value']:.2g}",
            ]
        )
    return header, rows


def load_records(paths: list[Path]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The cells, in table order: run-cell's of this checkout's world in the folders given
    (`<folder>/<column>/<row>.json`, as `results/`; archived worlds left out) and the cell files
    given; then the test records among the files given, in their order. Each checked
    (`experiments/cells.py`), with its path under "path". A table holds one cell a row and
    column: two cell files given for the same one (two sweeps' cells of one row) are refused,
    never one of them dropped unsaid."""
    folders = [path for path in paths if not path.is_file()]
    cells = [record for record in find_records(folders).records if "protocol" in record]
    files = [load_record(path) for path in paths if path.is_file()]
    cells += [record for record in files if "protocol" in record]
    tests = [record for record in files if "protocol" not in record]
    kept = [record for _, record in in_table_order(cells)]
    kept_files = {Path(record["path"]).resolve() for record in kept}
    for record in files:
        if "protocol" in record and Path(record["path"]).resolve() not in kept_files:
            other = next(other for other in kept if cell_key(other) == cell_key(record))
            row = row_key(record["method"], record.get("imagery"))
            raise ValueError(
                f"{record['path']} and {other['path']} are both the {row} cell of "
                f"{column_name(*column_of(record))}: name one of them at a time"
            )
    return kept, tests


def records_of_task(paths: list[Path], task: str) -> list[dict[str, Any]]:
    """Every record of `task` among `paths`, for a breakdown of its episodes: the newest cell a row
    of each folder (as the table) and every file, as given (two fits of one row side by side);
    each checked. ValueError where one cannot be read or none is of `task`."""
    cells, _ = load_records([path for path in paths if not path.is_file()])
    records = cells + [load_record(path) for path in paths if path.is_file()]
    records = [record for record in records if record["task"] == task]
    if not records:
        raise ValueError(f"no {task} cells or records among {', '.join(map(str, paths))}")
    return records


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter failures",
        description="Why the test episodes of run-cell's cells (or of test records) failed: "
        "each episode's scene is "
        "reset from its seed and its recorded action judged before the robot moves (picked another "
        "body, aimed off in position / tilt / yaw, aimed within tolerance but did not settle, "
        "failed in motion), and the failed picks that lay on the empty table counted apart. Needs "
        "the world the cells were measured in.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "cells",
        nargs="*",
        default=["results"],
        help="cell files, folders of cells (<folder>/<column>/<row>.json), or test record files "
        "(evaluate-checkpoints --split test, lightning test)",
    )
    parser.add_argument(
        "--json", type=Path, help="also write every episode's diagnosis to this JSON file"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    try:
        if args.json:
            check_writable("--json", args.json, file=True)
        cells, tests = load_records([Path(path) for path in args.cells])
        records = cells + tests
        if not records:
            raise FailureAnalysisError(
                f"no run-cell cells in {' '.join(args.cells)}; run `nerf-transporter run-cell` first"
            )
        for record in records:  # every one before the first replay
            check_replayable(record)
        analysed = []
        for record in records:
            diagnoses = diagnose_cell(record, progress=not args.no_progress)
            analysed.append((summary(record, diagnoses), diagnoses))
    except (OSError, ValueError) as error:  # cells it cannot read or replay, --json unwritable
        print(f"nerf-transporter failures: {error}", file=sys.stderr)
        return 2
    summaries = [entry for entry, _ in analysed]
    tables = [
        summary_table(summaries),
        binned_table(summaries, "success_by_target_tilt", TILT_BINS_DEG, "target tilt"),
        binned_table(
            summaries, "success_by_aim_tilt_error", TILT_ERROR_BINS_DEG, "aim's tilt error"
        ),
    ]
    if views := view_search_table(summaries):
        tables.append(views)
    if paired := paired_table(cells):
        tables.append(paired)
    sys.stdout.write("\n".join(markdown(*table) for table in tables))
    if args.json:
        payload = [entry | {"episodes_diagnosed": diagnoses} for entry, diagnoses in analysed]
        write_json(args.json, payload)
    return 0
