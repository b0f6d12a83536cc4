"""Does a flat SE(2) placement succeed on the four tasks? The 6-DoF oracle against flat places.

For the first N test seeds of each task and setting, the same episode is executed three times
(`VARIANTS`), each from a fresh reset of its seed:

- `oracle`: the task's 6-DoF oracle (place = target . inv(object) . pick, tilted with the target);
- `se2`: what a perfect Transporter-SE(2) outputs: the oracle action's heightmap labels (pick and
  place pixel, rotation bin) turned back into an action as `methods/transporter_se2.py` does:
  upright pick, flat place (roll = pitch = 0), pick and place z read from the fused RGB-D heightmap;
- `se2_centred`: the same flat policy imitating a place that puts the object's origin right above
  the origin of the oracle's target pose (the pose its action carries the object to), turned to
  that pose's eulerXYZ yaw (the one the anchor's check reads): a flat release aimed at the target
  itself rather than at the oracle's suction point on the tilted target. Per task (where each
  target lies: anchors/mira-world.md): block-insertion, the block's origin above the fixture's, at
  the fixture's yaw; place-red-in-green, the cube's origin above the target point of the green bowl
  the oracle chose, at the cube's own yaw (the oracle keeps it; the check ignores rotation);
  hanging-disks, the disk's centre above the target point on the stand's rod, at the target's yaw
  (the check ignores it); stacking-kits, the shape's origin above its target on the kit's dark copy
  of it, at the copy's yaw.

An execution is a function of (task, setting, seed, variant): every one resets its seed and
recomputes the oracle's action; the RGB-D heightmap is rendered once per seed for both flat variants
(rendering does not move the scene). Each execution is one JSON line appended to `--out` as soon as
it ends, with the world fingerprint, and a rerun with the same `--out` skips the executions already
there, so a long run can be stopped and resumed (processes run side by side write to separate files;
`--records` merges them). A seed whose execution raises is reported and left out, and the run ends
with status 1. Each record holds the target's tilt (angle of its normal from the vertical), both
success measures (the anchor's `success` and the project's `strict_success`, a motion failure
scoring 0 on both) with their errors, the *aim* (where the action would carry the object if the
suction held it rigidly, against the oracle's target: x-y offset, its component downhill along the
target's slope, roll-pitch and yaw errors), what the object touched when the suction released it,
whether its pose then already passed the anchor's check, how far it moved and turned after release,
and the time of the execution. The summary gives both rates with 95% Wilson intervals per task x
setting x variant, overall and per 10-degree band of the target's tilt, and those diagnostics
(`--markdown`: as tables for docs/six_dof.md).

    OMP_NUM_THREADS=1 python benchmarks/flat_placement.py --out flat_placement.jsonl
        [--tasks ...] [--settings normal challenging] [--episodes 100] [--variants ...]
    python benchmarks/flat_placement.py --records a.jsonl b.jsonl [--markdown] [--json]

docs/six_dof.md reports and reads these figures.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import time
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from tqdm import tqdm

from nerf_transporter import geometry as g
from nerf_transporter.console import HelpFormatter, progress_bar
from nerf_transporter.data.heightmap import heightmap_from_rgbd
from nerf_transporter.data.labels import Action, action_from_labels, heightmap_labels
from nerf_transporter.device_info import cpu_model
from nerf_transporter.evaluation.metrics import wilson_interval
from nerf_transporter.experiments.failures import carried_pose
from nerf_transporter.sim import TASKS, cameras, make_env
from nerf_transporter.sim.env import RavensEnv
from nerf_transporter.sim.fingerprint import world_fingerprint
from nerf_transporter.sim.tasks.base import SETTINGS, MatchTolerance
from nerf_transporter.splits import split_seed

VARIANTS = ("oracle", "se2", "se2_centred")
TILT_BAND_DEG = 10
MEASURES = ("success", "strict_success")
Key = tuple[str, str, int, str]


# -- the executions ------------------------------------------------------------------------------


def record_key(record: Mapping[str, Any]) -> Key:
    """(task, setting, seed, variant): what an execution is a function of."""
    return record["task"], record["setting"], record["seed"], record["variant"]


def test_seeds(episodes: int) -> list[int]:
    """The first `episodes` test seeds."""
    return [split_seed("test", index) for index in range(episodes)]


def tilt_deg(pose: g.Pose) -> float:
    """Angle (deg) of the pose's z axis from the vertical."""
    return math.degrees(math.acos(float(np.clip(g.quat_to_matrix(pose[1])[2, 2], -1.0, 1.0))))


def fused_height(env: RavensEnv) -> np.ndarray:
    """The fused top-down heightmap of the `rgbd` rig (arm at home) in the current scene."""
    rgbd = cameras.capture(env.client, cameras.rgbd_cameras(), depth=True)
    return heightmap_from_rgbd(rgbd, g.PIXEL_SIZE)[1]


def flat_policy_action(demonstration: Action, height: np.ndarray) -> Action:
    """A perfect Transporter-SE(2): `demonstration`'s labels back to an action, z from `height`."""
    labels = heightmap_labels(demonstration, g.PIXEL_SIZE, g.N_ROTATIONS)
    return action_from_labels(
        labels.pick_pixel,
        float(height[labels.pick_pixel]),
        labels.place_pixel,
        float(height[labels.place_pixel]),
        labels.rotation_bin,
        pixel_size=g.PIXEL_SIZE,
        n_rotations=g.N_ROTATIONS,
    )


def centred_demonstration(oracle: Action, object_pose: g.Pose) -> Action:
    """The oracle's pick, placed flat with the object's origin at its target's, at its yaw."""
    target = carried_pose(object_pose, oracle)
    _, _, yaw = g.quat_to_euler(target[1])
    flat_target = (np.asarray(target[0]), g.euler_to_quat(0.0, 0.0, yaw))
    place = g.multiply_poses(flat_target, g.invert_pose(object_pose), oracle["pick"])
    return {"pick": oracle["pick"], "place": place}


def aim(
    tolerance: MatchTolerance, object_pose: g.Pose, action: Action, target: g.Pose
) -> dict[str, Any]:
    """The anchor's check of where `action` carries the object (held rigidly) against `target`."""
    carried = carried_pose(object_pose, action)
    check = tolerance.check(carried, target)
    offset = (np.asarray(carried[0]) - np.asarray(target[0]))[:2]
    normal = g.quat_to_matrix(target[1])[:2, 2]
    slope = float(np.linalg.norm(normal))
    downhill = float(offset @ normal) / slope if slope > 1e-9 else 0.0
    return {
        "position_mm": 1000 * check["position_error"],
        "downhill_mm": 1000 * downhill,
        "tilt_deg": math.degrees(check["tilt_error"]),
        "yaw_deg": math.degrees(check["yaw_error"]),
        "passes": check["success"],
    }


def _errors(errors: Mapping[str, float]) -> dict[str, float]:
    """A check's errors (m, rad) in mm and degrees."""
    return {
        "position_mm": 1000 * errors["position_error"],
        "tilt_deg": math.degrees(errors["tilt_error"]),
        "yaw_deg": math.degrees(errors["yaw_error"]),
    }


def _touched(env: RavensEnv, bodies: Iterable[int]) -> str:
    """What the bodies the held object touches are: target, distractor, table, other or nothing."""
    touched, task = set(bodies), env.task
    for name, ids in (
        ("target", task.target_ids),
        ("distractor", task.distractor_ids),
        ("table", [env.table_id]),
    ):
        if touched & set(ids):
            return name
    return "other" if touched else "nothing"


def execute(env: RavensEnv, action: Action, target: g.Pose, object_pose: g.Pose) -> dict:
    """Step `action` in the scene just reset; the outcome, the aim and what happened at release."""
    robot, task = env.robot, env.task
    at_release: dict[str, Any] = {}
    release = robot.release

    # `release` is wrapped for this one step to read the object's pose and contacts when the
    # suction lets go (the simulation itself is untouched); kept only if the motion completed
    def recorded_release() -> None:
        """Note the held object's pose and contacts, then release it."""
        if robot.held_body is not None and not at_release:
            at_release["pose"] = task.object_pose(env)
            at_release["touching"] = _touched(env, robot.held_touching())
        release()

    record: dict[str, Any] = {"aim": aim(task.tolerance, object_pose, action, target)}
    robot.release = recorded_release
    try:
        _, _, _, _, info = env.step(action)
    finally:
        robot.release = release
    final = task.object_pose(env)
    record |= {
        "success": bool(info["success"]),
        "strict_success": bool(info["strict_success"]),
        "failure": info["failure"],
        "errors": _errors(info),
        "strict_errors": _errors(info["strict_errors"]),
        "final_speed_mm_s": 1000
        * float(np.linalg.norm(env.client.getBaseVelocity(task.object_id)[0])),
        "release": None,
    }
    if at_release and info["failure"] is None:
        pose = at_release["pose"]
        record["release"] = {
            "touching": at_release["touching"],
            "passes": any(task.tolerance.check(pose, t)["success"] for t in task.target_poses),
            "moved_mm": 1000 * float(np.linalg.norm(np.asarray(final[0]) - pose[0])),
            "turned_deg": math.degrees(
                g.rotation_angle(g.quat_to_matrix(pose[1]), g.quat_to_matrix(final[1]))
            ),
        }
    return record


def measure_seed(env: RavensEnv, seed: int, variants: Sequence[str]) -> Iterator[dict]:
    """One record per variant, each from a fresh reset; one heightmap for the flat variants."""
    height = None
    for variant in variants:
        start = time.perf_counter()
        env.reset(seed=seed)
        object_pose = env.task.object_pose(env)
        oracle = env.task.oracle(env)
        target = carried_pose(object_pose, oracle)
        if variant == "oracle":
            action = oracle
        else:
            if height is None:
                height = fused_height(env)
            demonstration = (
                oracle if variant == "se2" else centred_demonstration(oracle, object_pose)
            )
            action = flat_policy_action(demonstration, height)
        record = {"variant": variant, "target_tilt_deg": tilt_deg(target)}
        record |= execute(env, action, target, object_pose)
        yield record | {"wall_s": time.perf_counter() - start}


def measure(
    tasks: Sequence[str],
    settings: Sequence[str],
    seeds: Sequence[int],
    variants: Sequence[str],
    done: set[Key],
    out: TextIO | None,
) -> tuple[list[dict], int]:
    """Execute what `done` lacks, each record appended to `out`; (records, seeds that raised)."""
    fingerprint, cpu = world_fingerprint(), cpu_model()
    plan = {
        (task, setting): [
            (seed, pending)
            for seed in seeds
            if (pending := [v for v in variants if (task, setting, seed, v) not in done])
        ]
        for task in tasks
        for setting in settings
    }
    total = sum(len(pending) for runs in plan.values() for _, pending in runs)
    records, errors = [], 0
    with progress_bar(total, "flat placement", unit="execution") as bar:
        for (task, setting), runs in plan.items():
            if not runs:
                continue
            env = make_env(task, setting, rigs=())
            try:
                for seed, pending in runs:
                    bar.set_postfix(task=task, setting=setting, seed=seed)
                    count = 0
                    try:
                        for row in measure_seed(env, seed, pending):
                            record = {
                                "fingerprint": fingerprint,
                                "task": task,
                                "setting": setting,
                                "seed": seed,
                            }
                            record |= row | {"cpu": cpu}
                            records.append(record)
                            if out is not None:
                                out.write(json.dumps(record) + "\n")
                                out.flush()
                            count += 1
                            bar.update()
                    except Exception as error:  # a broken seed must not end a long run
                        errors += 1
                        tqdm.write(
                            f"{task} {setting} seed {seed}: {type(error).__name__}: {error} "
                            f"({len(pending) - count} executions not recorded)",
                            file=sys.stderr,
                        )
                        bar.update(len(pending) - count)
            finally:
                env.close()
    return records, errors


# -- records on disk -----------------------------------------------------------------------------


def load_records(paths: Sequence[Path]) -> list[dict]:
    """JSON-lines files merged, one record per execution; mixed worlds are refused (SystemExit)."""
    merged: dict[Key, dict] = {}
    where: dict[str, Path] = {}
    for path in paths:
        text = path.read_text()
        lines = text.splitlines()
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError as error:  # a write interrupted: skip it at the end
                if number == len(lines) and not text.endswith("\n"):
                    print(f"{path}: skipping its incomplete last line", file=sys.stderr)
                    continue
                raise SystemExit(f"{path}:{number}: not a JSON record ({error})") from error
            where.setdefault(record["fingerprint"], path)
            if len(where) > 1:
                worlds = "; ".join(f"{world} (in {file})" for world, file in where.items())
                raise SystemExit(
                    f"refusing to merge records of different worlds (world fingerprints {worlds}): "
                    "summarise each world's records separately"
                )
            key = record_key(record)
            previous = merged.setdefault(key, record)
            if any(previous[k] != record[k] for k in ("success", "strict_success", "failure")):
                raise SystemExit(
                    f"{path}:{number}: two records of {key} disagree: executions are meant to be "
                    "functions of (task, setting, seed, variant)"
                )
    return list(merged.values())


def recorded_keys(path: Path, fingerprint: str) -> set[Key]:
    """The executions `path` already holds (another world's: SystemExit), its cut line removed."""
    if not path.exists():
        return set()
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        print(f"{path}: cutting off its incomplete last line", file=sys.stderr)
        with path.open("r+b") as stream:
            stream.truncate(data.rfind(b"\n") + 1)
    records = load_records([path])
    other = {record["fingerprint"] for record in records} - {fingerprint}
    if other:
        raise SystemExit(
            f"{path} holds records of world fingerprint {other.pop()}, this world is "
            f"{fingerprint}: use another --out (or move that file away) rather than mix worlds"
        )
    return {record_key(record) for record in records}


# -- summary -------------------------------------------------------------------------------------


def rate(records: Sequence[dict], key: str = "success") -> dict:
    """How many of `records` have `key` true, out of how many, with the 95% Wilson interval."""
    successes, n = sum(bool(r[key]) for r in records), len(records)
    low, high = wilson_interval(successes, n)
    return {
        "successes": successes,
        "n": n,
        "rate": successes / n if n else None,
        "ci95": [low, high],
    }


def quantiles(values: Sequence[float]) -> dict:
    """Median, 10th and 90th percentiles and max; empty for no values."""
    if not values:
        return {}
    array = np.asarray(values, dtype=float)
    return {
        "median": float(np.median(array)),
        "p10": float(np.percentile(array, 10)),
        "p90": float(np.percentile(array, 90)),
        "max": float(array.max()),
    }


def tilt_band(tilt: float) -> str:
    """The `TILT_BAND_DEG`-wide band of a tilt (deg), e.g. "20-30"."""
    low = int(tilt // TILT_BAND_DEG) * TILT_BAND_DEG
    return f"{low}-{low + TILT_BAND_DEG}"


def _band_start(band: str) -> int:
    """The lower edge of a `tilt_band` label."""
    return int(band.split("-")[0])


def _by_outcome(records: Sequence[dict], value) -> dict:
    """Quantiles of `value(record)` over the successes and over the failures (None: left out)."""
    return {
        outcome: quantiles(
            [v for r in records if r["success"] is wanted and (v := value(r)) is not None]
        )
        for outcome, wanted in (("successes", True), ("failures", False))
    }


def summarise_variant(records: Sequence[dict]) -> dict:
    """Both rates, overall and per tilt band, and the diagnostics of one variant's records."""
    released = [r for r in records if r["release"] is not None]
    bands = sorted({tilt_band(r["target_tilt_deg"]) for r in records}, key=_band_start)
    return {
        "success": rate(records),
        "strict_success": rate(records, "strict_success"),
        "motion_failures": sum(r["failure"] is not None for r in records),
        "release_touching": dict(Counter(r["release"]["touching"] for r in released)),
        "release_passes": rate([r["release"] for r in released], "passes"),
        "moved_after_release_mm": _by_outcome(
            records, lambda r: None if r["release"] is None else r["release"]["moved_mm"]
        ),
        "aim_position_mm": _by_outcome(records, lambda r: r["aim"]["position_mm"]),
        "aim_downhill_mm": _by_outcome(records, lambda r: r["aim"]["downhill_mm"]),
        "wall_s": quantiles([r["wall_s"] for r in records]),
        "tilt_bands": {
            band: {
                "success": rate(inside),
                "strict_success": rate(inside, "strict_success"),
            }
            for band in bands
            if (inside := [r for r in records if tilt_band(r["target_tilt_deg"]) == band])
        },
    }


def summarise(records: Sequence[dict]) -> dict:
    """task -> setting -> variant -> `summarise_variant`, in the order of TASKS and SETTINGS."""
    summary: dict = {}
    for task in TASKS:
        for setting in SETTINGS:
            for variant in VARIANTS:
                runs = [r for r in records if record_key(r)[:2] == (task, setting)]
                runs = [r for r in runs if r["variant"] == variant]
                if runs:
                    per_setting = summary.setdefault(task, {}).setdefault(setting, {})
                    per_setting[variant] = summarise_variant(runs)
    return summary


def rate_text(figures: Mapping[str, Any]) -> str:
    """ "k/n = p% (low-high)" of a `rate`; "-" for none."""
    if not figures["n"]:
        return "-"
    low, high = figures["ci95"]
    return (
        f"{figures['successes']}/{figures['n']} = {100 * figures['rate']:.0f}% "
        f"({100 * low:.0f}-{100 * high:.0f})"
    )


def _medians(stats: Mapping[str, dict]) -> str:
    """ "successes / failures" medians of a `_by_outcome`."""
    return " / ".join(f"{s['median']:.1f}" if s else "-" for s in stats.values())


def tables(summary: Mapping[str, Any]) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, rows) of the tables: rates, rates per tilt band, diagnostics."""
    cells = [
        (task, setting, variant, figures)
        for task, per_task in summary.items()
        for setting, per_setting in per_task.items()
        for variant, figures in per_setting.items()
    ]
    rates = [
        [task, setting, f"`{variant}`", rate_text(f["success"]), rate_text(f["strict_success"])]
        + [str(f["motion_failures"])]
        for task, setting, variant, f in cells
    ]
    variants = [v for v in VARIANTS if any(cell[2] == v for cell in cells)]
    bands = []
    for task, per_task in summary.items():
        for setting, per_setting in per_task.items():
            labels = {band for f in per_setting.values() for band in f["tilt_bands"]}
            for band in sorted(labels, key=_band_start):
                row = [task, setting, band]
                for variant in variants:
                    figures = per_setting.get(variant, {}).get("tilt_bands", {}).get(band)
                    row += [rate_text(figures[m]) if figures else "-" for m in MEASURES]
                bands.append(row)
    diagnostics = [
        [
            task,
            setting,
            f"`{variant}`",
            ", ".join(f"{k} {v}" for k, v in sorted(f["release_touching"].items())) or "-",
            rate_text(f["release_passes"]),
            _medians(f["moved_after_release_mm"]),
            _medians(f["aim_position_mm"]),
            _medians(f["aim_downhill_mm"]),
            f"{f['wall_s']['median']:.1f}",
        ]
        for task, setting, variant, f in cells
    ]
    return [
        (
            "Success (anchor's check) and strict success, 95% Wilson intervals",
            ["task", "setting", "variant", "success", "strict success", "motion failures"],
            rates,
        ),
        (
            "Per band of the target's tilt (deg, its normal from the vertical)",
            ["task", "setting", "tilt (deg)"]
            + [f"`{v}` {m.replace('_', ' ')}" for v in variants for m in MEASURES],
            bands,
        ),
        (
            "What happened (medians over successes / failures)",
            [
                "task",
                "setting",
                "variant",
                "touching at release",
                "pose at release passes",
                "moved after release (mm)",
                "aim x-y offset (mm)",
                "aim downhill (mm)",
                "s per execution",
            ],
            diagnostics,
        ),
    ]


def format_table(header: Sequence[str], rows: Sequence[Sequence[str]], markdown: bool) -> str:
    """A table as Markdown, or as plain text in aligned columns."""
    if markdown:
        lines = [header, ["---"] * len(header), *rows]
        return "\n".join("| " + " | ".join(line) + " |" for line in lines)
    widths = [max(len(line[k]) for line in [header, *rows]) for k in range(len(header))]
    return "\n".join(
        "  ".join(cell.ljust(width) for cell, width in zip(line, widths, strict=True)).rstrip()
        for line in [header, *rows]
    )


def summary_text(records: Sequence[dict], markdown: bool) -> str:
    """What the records came from, then the summary's tables."""
    fingerprints = sorted({r["fingerprint"] for r in records})
    cpus = sorted({r["cpu"] for r in records})
    head = (
        f"{len(records)} executions, world fingerprint {', '.join(fingerprints) or '-'}, "
        f"{sum(r['wall_s'] for r in records):.0f} s of execution on {'; '.join(cpus) or '-'}"
    )
    parts = [head]
    for title, header, rows in tables(summarise(records)):
        parts += [
            f"### {title}" if markdown else f"== {title} ==",
            format_table(header, rows, markdown),
        ]
    return "\n\n".join(parts)


# -- command line --------------------------------------------------------------------------------


class _Help(argparse.RawDescriptionHelpFormatter, HelpFormatter):
    """The project's `--help` (defaults shown) with this docstring's layout kept."""


def main(argv: Sequence[str] | None = None) -> int:
    """Simulate (or re-summarise saved records), print the summary; 1 if a seed raised."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=_Help)
    for name, choices, default in (
        ("tasks", list(TASKS), list(TASKS)),
        ("settings", SETTINGS, ["normal", "challenging"]),
        ("variants", VARIANTS, list(VARIANTS)),
    ):
        parser.add_argument(
            f"--{name}",
            nargs="+",
            choices=choices,
            default=default,
            metavar=name[:-1].upper(),
            help=f"any of {', '.join(choices)}",
        )
    parser.add_argument("--episodes", type=int, default=100, help="test seeds per task and setting")
    parser.add_argument(
        "--out",
        type=Path,
        metavar="FILE",
        help="append each execution's record to FILE as one JSON line, skipping the executions "
        "FILE already holds (a rerun resumes)",
    )
    parser.add_argument(
        "--records",
        type=Path,
        nargs="+",
        metavar="FILE",
        help="summarise these --out files (merged) instead of simulating",
    )
    parser.add_argument("--markdown", action="store_true", help="print the tables as Markdown")
    parser.add_argument(
        "--json",
        action="store_true",
        help="also print the summary and the records as one JSON line",
    )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be at least 1, got {args.episodes}")
    if args.records and args.out:
        parser.error("--records summarises saved records; --out is for a simulating run")
    seeds, errors = test_seeds(args.episodes), 0
    if args.records:
        records = load_records(args.records)
    else:
        done = recorded_keys(args.out, world_fingerprint()) if args.out else set()
        with open(args.out, "a") if args.out else contextlib.nullcontext() as out:
            records, errors = measure(args.tasks, args.settings, seeds, args.variants, done, out)
        if args.out:
            records = load_records([args.out])
    wanted = {
        (t, s, seed, v)
        for t in args.tasks
        for s in args.settings
        for seed in seeds
        for v in args.variants
    }
    records = [r for r in records if record_key(r) in wanted]
    print(summary_text(records, args.markdown))
    if args.json:
        print(json.dumps({"summary": summarise(records), "records": records}))
    if errors:
        print(
            f"{errors} seeds raised an error and are not (fully) recorded; a rerun with the same "
            "--out retries them",
            file=sys.stderr,
        )
    return 1 if errors else 0


if __name__ == "__main__":
    raise SystemExit(main())
