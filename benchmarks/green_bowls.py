"""place-red-in-green mira records: success and the view search by the number of green bowls.

A place-red-in-green scene has one to three green bowls, each tilted its own way, and the block
succeeds in any of them. The view search's `true_view` is the view of the bowl the training label
chooses (the oracle's: the one nearest the block), so a place in another green bowl counts as a
search off its view even where it searched that bowl's view well. This replays each test seed's
reset (no robot motion) and, per record, gives success and the view search by the scene's number
of green bowls, with the chosen view scored twice: against the true view (as recorded) and against
the view of the green bowl nearest the place (the bowl the policy went for). Each entry is
"successes/episodes; within one grid step of the true view / of the bowl aimed at".

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/green_bowls.py RECORD.json [...] [--json]

docs/budget.md reads these figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.evaluation.view_search import view_steps
from nerf_transporter.experiments.failures import records_of_task
from nerf_transporter.sim import make_env

TASK = "place-red-in-green"
FIGURES = ("episodes", "successes", "searched", "true_view", "aimed_view")


Bowl = tuple[tuple[float, float, float], float, float]  # origin xyz, roll, pitch


def scene_bowls(setting: str, seeds: list[int]) -> dict[int, list[Bowl]]:
    """seed -> the green bowls of its scene as (origin xyz, roll, pitch), as the task draws them."""
    env = make_env(TASK, setting)
    try:
        bowls = {}
        for seed in seeds:
            env.reset(seed=seed)
            bowls[seed] = [
                (tuple(float(v) for v in position), *(float(a) for a in g.quat_to_euler(quat)[:2]))
                for position, quat in env.task.target_poses
            ]
        return bowls
    finally:
        env.close()


def aimed_view_steps(
    place: np.ndarray, chosen: np.ndarray, bowls: list[Bowl], grid: np.ndarray
) -> int:
    """Grid steps between the chosen view and the view nearest the tilt of the green bowl whose
    origin lies nearest the place, in x and y."""
    place = np.asarray(place, dtype=float)
    distances = [np.linalg.norm(np.asarray(origin[:2]) - place[:2]) for origin, _, _ in bowls]
    _, roll, pitch = bowls[int(np.argmin(distances))]
    return view_steps(chosen, grid[g.nearest_view(roll, pitch, grid)], grid)


def by_bowl_count(
    record: dict[str, Any], bowls: dict[int, list[Bowl]]
) -> dict[int, dict[str, int]]:
    """number of green bowls -> episodes, successes, episodes with a view search, and those whose
    chosen view lies within one grid step of the true view / of the bowl aimed at (erred
    episodes left out)."""
    grid = g.view_grid(record["setting"])
    counts: dict[int, dict[str, int]] = {}
    for episode in record["episode_results"]:
        if episode.get("error"):
            continue
        scene = bowls[episode["seed"]]
        tally = counts.setdefault(len(scene), dict.fromkeys(FIGURES, 0))
        tally["episodes"] += 1
        tally["successes"] += int(episode["success"])
        search, action = episode.get("view_search"), episode.get("action")
        if not search or not action:
            continue
        tally["searched"] += 1
        tally["true_view"] += int(search["view_steps"] <= 1)
        place = np.asarray(action["place"][:3])
        steps = aimed_view_steps(place, search["chosen_view"], scene, grid)
        tally["aimed_view"] += int(steps <= 1)
    return dict(sorted(counts.items()))


def entry_text(tally: dict[str, int]) -> str:
    """ "successes/episodes; true view % / aimed bowl's view %" ("-" where nothing searched)."""
    text = f"{tally['successes']}/{tally['episodes']}"
    if not tally["searched"]:
        return f"{text}; -"
    shares = (tally[key] / tally["searched"] for key in ("true_view", "aimed_view"))
    return f"{text}; " + " / ".join(f"{share:.0%}" for share in shares)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "records", type=Path, nargs="+", help="mira cell files or folders, or test record files"
    )
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    args = parser.parse_args(argv)
    try:
        records = records_of_task(args.records, TASK)
    except (OSError, ValueError) as error:  # a cell or record it cannot read, or none of TASK
        print(f"green_bowls.py: {error}", file=sys.stderr)
        return 2
    print(
        "| record | setting | all | one green bowl | two | three |\n| --- | --- | --- | --- | --- | --- |"
    )
    summary = []
    for record in records:
        seeds = sorted({e["seed"] for e in record["episode_results"]})
        counts = by_bowl_count(record, scene_bowls(record["setting"], seeds))
        total = {key: sum(tally[key] for tally in counts.values()) for key in FIGURES}
        cells = [entry_text(counts[n]) if n in counts else "-" for n in (1, 2, 3)]
        print(
            f"| {record['path']} | {record['setting']} | {entry_text(total)} | {' | '.join(cells)} |"
        )
        summary.append({"record": str(record["path"]), "all": total, "by_bowls": counts})
    if args.json:
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
