"""Why does a flat SE(2) placement succeed on block-insertion? The 6-DoF oracle against flat places.

For the first N test seeds of each setting, the same episode is executed three times:

- `oracle`: the task's 6-DoF oracle (place at target . inv(object) . pick, the fixture's tilt);
- `se2`: what a perfect Transporter-SE(2) outputs: the oracle action's heightmap labels (pick and
  place pixel, rotation bin) turned back into an action as `methods/transporter_se2.py` does: upright
  pick, flat place (roll = pitch = 0), pick and place z read from the fused RGB-D heightmap;
- `se2_centred`: the same flat policy imitating a placement that puts the block's centre right above
  the fixture's centre at the fixture's yaw (rather than the oracle's suction point above its tilted
  place), to see whether aiming at the slot's middle helps a flat placement.

Each execution records the fixture's tilt (angle of its normal from the vertical), the outcome, the
task's pose errors (`Tolerance.check`) on the settled pose and on the pose at the moment the suction
releases the block, what the block touched then, how far it moved and turned after release, and
where it ended in the fixture's frame (`normal_offset_mm`: 0 when seated on the slot floor). The
summary gives success rates with 95% Wilson intervals, success against the fixture's tilt, what
happens between release and rest for the flat successes, and how the successes fare under stricter
tolerances (recomputed from the recorded errors; the task itself is unchanged).

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/flat_placement.py \
        [--episodes 100] [--settings normal challenging] [--json]
    python benchmarks/flat_placement.py --records <saved --json output> [--episodes 50]

docs/six_dof.md reports and reads these figures.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.data.heightmap import heightmap_from_rgbd
from nerf_transporter.data.labels import Action, action_from_labels, heightmap_labels
from nerf_transporter.device_info import cpu_model
from nerf_transporter.evaluation.failures import carried_pose
from nerf_transporter.evaluation.metrics import wilson_interval
from nerf_transporter.sim import TASKS, make_env
from nerf_transporter.sim.env import RavensEnv
from nerf_transporter.sim.fingerprint import world_fingerprint
from nerf_transporter.sim.tasks.base import SETTINGS, Tolerance
from nerf_transporter.splits import split_seed

TASK = "block-insertion"
VARIANTS = ("oracle", "se2", "se2_centred")
TILT_BINS_DEG = (0, 10, 20, 30, 40, 50, 60)
AIM_BINS_MM = (0, 5, 10, 15, 20, 30, 1000)
DOWNHILL_BINS_MM = (-1000, -10, -5, 0, 5, 10, 15, 20, 30, 1000)
SEATED_MM = 5.0  # a block whose centre is within this of the slot floor's position along the normal
STRICT = {
    "position 1 cm": Tolerance(0.01, math.radians(15), math.radians(15)),
    "tilt 5 deg": Tolerance(0.02, math.radians(5), math.radians(15)),
    "yaw 5 deg": Tolerance(0.02, math.radians(15), math.radians(5)),
    "1 cm, 5 deg, 5 deg": Tolerance(0.01, math.radians(5), math.radians(5)),
}


def axis_angle_deg(rotation_a: np.ndarray, rotation_b: np.ndarray) -> float:
    """Angle (deg) between the z axes of two rotations: a tilt that ignores yaw."""
    cos = float(np.dot(rotation_a[:, 2], rotation_b[:, 2]))
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


def pose_errors(pose: g.Pose, target: g.Pose, tolerance: Tolerance) -> dict:
    """The task's check of `pose` against `target`, in mm and degrees, with the pose in the target's
    frame: `normal_offset_mm` along the fixture's normal, `in_plane_offset_mm` across it, and the
    angle between the two z axes (`axis_tilt_error_deg`)."""
    check = tolerance.check(pose, target)
    target_rotation = g.quat_to_matrix(target[1])
    local = target_rotation.T @ (np.asarray(pose[0]) - np.asarray(target[0]))
    return {
        "success": check["success"],
        "position_error_mm": 1000 * check["position_error"],
        "tilt_error_deg": math.degrees(check["tilt_error"]),
        "yaw_error_deg": math.degrees(check["yaw_error"]),
        "axis_tilt_error_deg": axis_angle_deg(target_rotation, g.quat_to_matrix(pose[1])),
        "normal_offset_mm": 1000 * float(local[2]),
        "in_plane_offset_mm": 1000 * float(np.linalg.norm(local[:2])),
    }


def flat_policy_action(
    demonstration: Action, height: np.ndarray, pixel_size: float, n_rotations: int
) -> Action:
    """What a Transporter-SE(2) that predicted the labels of `demonstration` exactly would do: pixels
    and rotation bin from the labels, pick and place z from the heightmap, no tilt."""
    labels = heightmap_labels(demonstration, pixel_size, n_rotations)
    return action_from_labels(
        labels.pick_pixel,
        float(height[labels.pick_pixel]),
        labels.place_pixel,
        float(height[labels.place_pixel]),
        labels.rotation_bin,
        pixel_size=pixel_size,
        n_rotations=n_rotations,
    )


def centred_demonstration(env: RavensEnv, oracle: Action) -> Action:
    """The oracle's pick, placed so that the block lies flat with its centre at the fixture's centre
    and its yaw the fixture's."""
    target = env.task.target_poses[0]
    _, _, yaw = g.quat_to_euler(target[1])
    flat_target = (np.asarray(target[0]), g.euler_to_quat(0.0, 0.0, yaw))
    object_pose = env.task.object_pose(env)
    place = g.multiply_poses(flat_target, g.invert_pose(object_pose), oracle["pick"])
    return {"pick": oracle["pick"], "place": place}


def aim(env: RavensEnv, action: Action) -> dict:
    """Where `action` carries the block, before anything touches it: the horizontal offset of the
    block's centre from the fixture's centre (`aim_offset_mm`), its component downhill along the
    fixture's slope (`aim_downhill_mm`, negative: uphill) and the yaw error of the block."""
    target = env.task.target_poses[0]
    carried = carried_pose(env.task.object_pose(env), action)
    offset = (np.asarray(carried[0]) - np.asarray(target[0]))[:2]
    normal = g.quat_to_matrix(target[1])[:2, 2]
    slope = np.linalg.norm(normal)
    downhill = float(offset @ normal / slope) if slope > 1e-9 else 0.0
    _, _, carried_yaw = g.quat_to_euler(carried[1])
    _, _, target_yaw = g.quat_to_euler(target[1])
    return {
        "aim_offset_mm": 1000 * float(np.linalg.norm(offset)),
        "aim_downhill_mm": 1000 * downhill,
        "aim_yaw_error_deg": abs(math.degrees(float(g.wrap_angle(carried_yaw - target_yaw)))),
    }


def execute(env: RavensEnv, action: Action) -> dict:
    """Step `action`; the outcome with the pose errors at release and after settling.

    The robot's `release` is wrapped for this one step to read the block's pose and contacts at the
    moment the suction lets go (the simulation itself is untouched)."""
    robot, task = env.robot, env.task
    target = task.target_poses[0]
    at_release: dict = {}
    release = robot.release

    def recorded_release() -> None:
        if robot.held_body is not None and not at_release:
            at_release["pose"] = task.object_pose(env)
            touched = set(robot.held_touching())
            at_release["touching"] = (
                "fixture"
                if touched & set(task.target_ids)
                else "table"
                if env.table_id in touched
                else "other"
                if touched
                else "nothing"
            )
        release()

    record = aim(env, action)
    robot.release = recorded_release
    try:
        _, reward, _, _, info = env.step(action)
    finally:
        robot.release = release
    final = task.object_pose(env)
    record |= {
        "success": bool(reward),
        "failure": info["failure"],
        "final": pose_errors(final, target, task.tolerance),
        "speed_mm_s": 1000 * float(np.linalg.norm(env.client.getBaseVelocity(task.object_id)[0])),
    }
    if at_release:
        pose = at_release["pose"]
        record["release"] = pose_errors(pose, target, task.tolerance)
        record["release"]["touching"] = at_release["touching"]
        record["release"]["block_tilt_deg"] = axis_angle_deg(np.eye(3), g.quat_to_matrix(pose[1]))
        record["moved_after_release_mm"] = 1000 * float(np.linalg.norm(final[0] - pose[0]))
        record["turned_after_release_deg"] = math.degrees(
            g.rotation_angle(g.quat_to_matrix(pose[1]), g.quat_to_matrix(final[1]))
        )
    if record["success"] != record["final"]["success"]:
        raise RuntimeError(f"the task's reward {reward} disagrees with its tolerance check")
    return record


def measure_seed(
    envs: dict[str, RavensEnv], setting: str, seed: int, pixel_size: float, n_rotations: int
) -> list[dict]:
    """The three executions of one seed (`VARIANTS`), each from a fresh reset."""
    oracle_env, flat_env = envs["oracle"], envs["flat"]
    oracle_env.reset(seed=seed)
    target = oracle_env.task.target_poses[0]
    roll, pitch, _ = g.quat_to_euler(target[1])
    episode = {
        "setting": setting,
        "seed": seed,
        "fixture_roll_deg": math.degrees(roll),
        "fixture_pitch_deg": math.degrees(pitch),
        "fixture_tilt_deg": axis_angle_deg(np.eye(3), g.quat_to_matrix(target[1])),
    }
    rows = [
        episode | {"variant": "oracle"} | execute(oracle_env, oracle_env.task.oracle(oracle_env))
    ]
    demonstrations: dict[str, Callable[[RavensEnv, Action], Action]] = {
        "se2": lambda env, oracle: oracle,
        "se2_centred": centred_demonstration,
    }
    for variant, demonstration in demonstrations.items():
        observation, _ = flat_env.reset(seed=seed)
        _, height = heightmap_from_rgbd(observation["rgbd"], pixel_size)
        oracle = flat_env.task.oracle(flat_env)
        action = flat_policy_action(
            demonstration(flat_env, oracle), height, pixel_size, n_rotations
        )
        rows.append(episode | {"variant": variant} | execute(flat_env, action))
    return rows


def measure(
    settings: Sequence[str], episodes: int, pixel_size: float, n_rotations: int
) -> list[dict]:
    """Per-execution records for the first `episodes` test seeds of each setting."""
    rows = []
    for setting in settings:
        envs = {
            "oracle": make_env(TASK, setting, rigs=("state",)),
            "flat": make_env(TASK, setting, rigs=("state", "rgbd")),
        }
        try:
            start = time.perf_counter()
            for index in range(episodes):
                rows += measure_seed(
                    envs, setting, split_seed("test", index), pixel_size, n_rotations
                )
                if (index + 1) % 10 == 0:
                    print(
                        f"{setting}: {index + 1}/{episodes} seeds, "
                        f"{time.perf_counter() - start:.0f} s",
                        file=sys.stderr,
                    )
        finally:
            for env in envs.values():
                env.close()
    return rows


@dataclass(frozen=True)
class Rate:
    """`successes` out of `n` executions, with its 95% Wilson interval."""

    successes: int
    n: int

    def to_json(self) -> dict:
        low, high = wilson_interval(self.successes, self.n)
        rate = self.successes / self.n if self.n else float("nan")
        return {"successes": self.successes, "n": self.n, "rate": rate, "ci95": [low, high]}

    def text(self) -> str:
        if not self.n:
            return "-"
        low, high = wilson_interval(self.successes, self.n)
        return (
            f"{self.successes}/{self.n} = {100 * self.successes / self.n:.0f}% "
            f"({100 * low:.0f}-{100 * high:.0f})"
        )


def rate_of(rows: Sequence[dict], success: Callable[[dict], bool] = lambda r: r["success"]) -> Rate:
    return Rate(sum(bool(success(row)) for row in rows), len(rows))


def select(rows: Sequence[dict], **fields: object) -> list[dict]:
    return [row for row in rows if all(row[k] == v for k, v in fields.items())]


def binned_rates(rows: Sequence[dict], key: str, edges: Sequence[float]) -> dict[str, dict]:
    """Success rate per bin [low, high) of `row[key]`, in the order of `edges`; empty bins are left
    out, a value outside the edges is a ValueError."""
    outside = [row[key] for row in rows if not edges[0] <= row[key] < edges[-1]]
    if outside:
        raise ValueError(f"{key} {outside[0]:.1f} is outside the bins {tuple(edges)}")
    rates = {}
    for low, high in zip(edges, edges[1:], strict=False):
        inside = [row for row in rows if low <= row[key] < high]
        if inside:
            rates[f"{low} to {high}"] = rate_of(inside).to_json()
    return rates


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


def passes(errors: dict, tolerance: Tolerance) -> bool:
    """Whether recorded errors (mm, deg) are within `tolerance`."""
    return (
        errors["position_error_mm"] <= 1000 * tolerance.position
        and (tolerance.tilt is None or errors["tilt_error_deg"] <= math.degrees(tolerance.tilt))
        and (tolerance.yaw is None or errors["yaw_error_deg"] <= math.degrees(tolerance.yaw))
    )


def summarise(rows: Sequence[dict]) -> dict:
    """The figures of docs/six_dof.md from the per-execution records."""
    summary: dict = {}
    tilt_tolerance = math.degrees(TASKS[TASK].tolerance.tilt)
    for setting in dict.fromkeys(row["setting"] for row in rows):
        per_setting: dict = {"variants": {}}
        for variant in VARIANTS:
            runs = select(rows, setting=setting, variant=variant)
            if not runs:
                continue
            successes = [row for row in runs if row["success"]]
            with_release = [row for row in successes if "release" in row]
            failures = [row for row in runs if not row["success"]]
            unseated = [r for r in successes if abs(r["final"]["normal_offset_mm"]) > SEATED_MM]
            per_setting["variants"][variant] = {
                "rate": rate_of(runs).to_json(),
                "motion_failures": sum(row["failure"] is not None for row in runs),
                "release_touching": _counts(
                    r["release"]["touching"] for r in runs if "release" in r
                ),
                "release_would_pass": rate_of(
                    [row for row in runs if "release" in row], lambda r: r["release"]["success"]
                ).to_json(),
                "successes": {
                    "fixture_tilt_deg": quantiles([r["fixture_tilt_deg"] for r in successes]),
                    "aim_offset_mm": quantiles([r["aim_offset_mm"] for r in successes]),
                    "aim_downhill_mm": quantiles([r["aim_downhill_mm"] for r in successes]),
                    "aim_yaw_error_deg": quantiles([r["aim_yaw_error_deg"] for r in successes]),
                    "release_block_tilt_deg": quantiles(
                        [r["release"]["block_tilt_deg"] for r in with_release]
                    ),
                    "release_axis_tilt_error_deg": quantiles(
                        [r["release"]["axis_tilt_error_deg"] for r in with_release]
                    ),
                    "release_normal_offset_mm": quantiles(
                        [r["release"]["normal_offset_mm"] for r in with_release]
                    ),
                    "turned_after_release_deg": quantiles(
                        [r["turned_after_release_deg"] for r in with_release]
                    ),
                    "moved_after_release_mm": quantiles(
                        [r["moved_after_release_mm"] for r in with_release]
                    ),
                    "final": {
                        key: quantiles([r["final"][key] for r in successes])
                        for key in (
                            "position_error_mm",
                            "tilt_error_deg",
                            "axis_tilt_error_deg",
                            "yaw_error_deg",
                            "normal_offset_mm",
                            "in_plane_offset_mm",
                        )
                    },
                    "seated": len(successes) - len(unseated),
                    "unseated": {
                        "count": len(unseated),
                        **{
                            key: quantiles([r["final"][key] for r in unseated])
                            for key in (
                                "normal_offset_mm",
                                "tilt_error_deg",
                                "axis_tilt_error_deg",
                                "position_error_mm",
                            )
                        },
                    },
                    "axis_tilt_beyond_tolerance": sum(
                        r["final"]["axis_tilt_error_deg"] > tilt_tolerance for r in successes
                    ),
                    "strict_tolerances": {
                        name: sum(passes(r["final"], tolerance) for r in successes)
                        for name, tolerance in STRICT.items()
                    },
                },
                "failures": {
                    "fixture_tilt_deg": quantiles([r["fixture_tilt_deg"] for r in failures]),
                    "aim_offset_mm": quantiles([r["aim_offset_mm"] for r in failures]),
                    "aim_downhill_mm": quantiles([r["aim_downhill_mm"] for r in failures]),
                    "release_normal_offset_mm": quantiles(
                        [r["release"]["normal_offset_mm"] for r in failures if "release" in r]
                    ),
                    "final_normal_offset_mm": quantiles(
                        [r["final"]["normal_offset_mm"] for r in failures]
                    ),
                    "final_position_error_mm": quantiles(
                        [r["final"]["position_error_mm"] for r in failures]
                    ),
                },
            }
        per_setting["tilt_bins"] = {
            variant: binned_rates(
                select(rows, setting=setting, variant=variant), "fixture_tilt_deg", TILT_BINS_DEG
            )
            for variant in per_setting["variants"]
        }
        for key, edges in (("aim_offset_mm", AIM_BINS_MM), ("aim_downhill_mm", DOWNHILL_BINS_MM)):
            per_setting[f"{key}_bins"] = {
                variant: binned_rates(select(rows, setting=setting, variant=variant), key, edges)
                for variant in VARIANTS[1:]
            }
        summary[setting] = per_setting
    return summary


def _counts(values) -> dict[str, int]:
    counts: dict[str, int] = {}
    for value in values:
        counts[value] = counts.get(value, 0) + 1
    return dict(sorted(counts.items()))


def _range_text(stats: dict) -> str:
    if not stats:
        return "-"
    return (
        f"median {stats['median']:.1f} (10-90%: {stats['p10']:.1f} to {stats['p90']:.1f}, "
        f"max {stats['max']:.1f})"
    )


def _rate_text(rate: dict) -> str:
    return Rate(rate["successes"], rate["n"]).text()


def _print_bins(title: str, bins: dict[str, dict[str, dict]]) -> None:
    print(f"success by {title}:")
    labels = sorted(
        {label for rates in bins.values() for label in rates},
        key=lambda text: float(text.split(" to ")[0]),
    )
    print(f"  {'':>14}  " + "".join(f"{variant:<24}" for variant in bins))
    for label in labels:
        cells = "".join(
            f"{_rate_text(rates[label]) if label in rates else '-':<24}" for rates in bins.values()
        )
        print(f"  {label:>14}  {cells}")


def _print_stats(title: str, stats: dict, indent: str = "  ") -> None:
    print(f"{indent}{title}:")
    for key, value in stats.items():
        if isinstance(value, dict) and value and "median" not in value:
            _print_stats(key, value, indent + "  ")
        else:
            text = _range_text(value) if isinstance(value, dict) else str(value)
            print(f"{indent}  {key:<30}{text}")


def print_summary(summary: dict) -> None:
    for setting, figures in summary.items():
        print(f"\n== {TASK}, {setting} ==")
        for variant, v in figures["variants"].items():
            print(
                f"{variant:<12} {_rate_text(v['rate']):<24} motion failures "
                f"{v['motion_failures']}; pose at release within tolerance: "
                f"{_rate_text(v['release_would_pass'])}; touching at release: "
                f"{v['release_touching']}"
            )
        _print_bins("fixture tilt (deg)", figures["tilt_bins"])
        _print_bins(
            "aim offset of the block's centre from the slot's (mm)", figures["aim_offset_mm_bins"]
        )
        _print_bins("downhill component of that offset (mm)", figures["aim_downhill_mm_bins"])
        for variant, v in figures["variants"].items():
            n = v["rate"]["successes"]
            _print_stats(f"{variant} successes ({n})", v["successes"], "")
            _print_stats(f"{variant} failures ({v['rate']['n'] - n})", v["failures"], "")


def load_records(path: str) -> tuple[dict, list[dict]]:
    """(provenance, records) from the output of a run with --json (its last line)."""
    lines = Path(path).read_text().splitlines()
    try:
        data = json.loads(lines[-1])
        return data["provenance"], data["records"]
    except (IndexError, json.JSONDecodeError, KeyError, TypeError) as error:
        raise SystemExit(
            f"{path}: its last line is not the JSON of a run with --json ({error})"
        ) from error


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=100, help="test seeds per setting")
    parser.add_argument(
        "--settings", nargs="+", choices=SETTINGS, default=["normal", "challenging"]
    )
    parser.add_argument("--pixel-size", type=float, default=g.PIXEL_SIZE)
    parser.add_argument("--rotations", type=int, default=g.N_ROTATIONS, help="rotation bins")
    parser.add_argument(
        "--json", action="store_true", help="also print the summary and every record as JSON"
    )
    parser.add_argument(
        "--records",
        metavar="PATH",
        help="summarise the output of an earlier run with --json instead of simulating (its first "
        "--episodes test seeds per setting)",
    )
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be at least 1, got {args.episodes}")
    if args.records:
        provenance, rows = load_records(args.records)
        last_seed = split_seed("test", args.episodes - 1)
        rows = [r for r in rows if r["seed"] <= last_seed and r["setting"] in args.settings]
        provenance["settings"] = [name for name in provenance["settings"] if name in args.settings]
        provenance["test_seeds_per_setting"] = min(
            args.episodes, provenance["test_seeds_per_setting"]
        )
    else:
        start = time.perf_counter()
        rows = measure(args.settings, args.episodes, args.pixel_size, args.rotations)
        provenance = {
            "task": TASK,
            "settings": args.settings,
            "test_seeds_per_setting": args.episodes,
            "pixel_size": args.pixel_size,
            "n_rotations": args.rotations,
            "wall_s": round(time.perf_counter() - start),
            "cpu": cpu_model(),
            "world_fingerprint": world_fingerprint(),
        }
    summary = summarise(rows)
    print(", ".join(f"{key} {value}" for key, value in provenance.items()))
    print_summary(summary)
    if args.json:
        print(json.dumps({"provenance": provenance, "summary": summary, "records": rows}))


if __name__ == "__main__":
    main()
