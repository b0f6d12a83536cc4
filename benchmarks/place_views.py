"""Through which views mira placed: each test episode's place view against the training grid.

mira places at a pixel of one view of its grid, oriented R_view . Rz(theta)
(`data/labels.action_from_labels` without a tilt), so the view's roll and pitch are the first two
xyz Euler angles of the recorded place orientation. For each mira evaluation record or cell this
counts the episodes whose place view lies beyond the Normal grid (the views mira is trained on)
and those whose place position lies outside the workspace, with the successes among them: a
policy trained on the Normal grid and tested on the Challenging one (`evaluate-checkpoints
--setting challenging`) meets views it has never seen.

    OMP_NUM_THREADS=1 PYTHONPATH=src python benchmarks/place_views.py \
        logs/colour/hanging-disks/mira-oracle/<run>/version_0/evaluation/*-test-*.json [--json]

docs/failures.md reports and reads these figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.methods.mira import over_workspace

ANGLE_SLACK = 1e-3  # rad: a view on the grid's edge read back from a stored quaternion


def place_view(action: dict) -> tuple[float, float]:
    """(roll, pitch) in radians of the view a mira action placed through."""
    roll, pitch, _ = g.quat_to_euler(np.asarray(action["place"][3:], dtype=float))
    return float(roll), float(pitch)


def place_view_summary(record: dict, limit: float) -> dict:
    """Counts of a record's episodes (erred ones left out) by place view and place position."""
    episodes = [e for e in record["episode_results"] if e.get("error") is None]
    angles = [max(map(abs, place_view(e["action"]))) for e in episodes]
    beyond = [angle > limit + ANGLE_SLACK for angle in angles]
    outside = [not over_workspace(e["action"]["place"][:3]) for e in episodes]
    wins = [bool(e["success"]) for e in episodes]
    return {
        "setting": record["setting"],
        "episodes": len(episodes),
        "successes": sum(wins),
        "beyond_grid": sum(beyond),
        "beyond_grid_successes": sum(b and w for b, w in zip(beyond, wins, strict=True)),
        "outside_workspace": sum(outside),
        "outside_workspace_successes": sum(o and w for o, w in zip(outside, wins, strict=True)),
        "median_view_angle_deg": float(np.degrees(np.median(angles))) if angles else 0.0,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("records", type=Path, nargs="+", help="mira evaluation records or cells")
    parser.add_argument("--json", action="store_true", help="end with one JSON line")
    args = parser.parse_args(argv)
    limit = float(np.abs(g.view_grid("normal")).max())
    print(
        f"| record | setting | episodes | successes | place view beyond the Normal grid "
        f"(+-{np.degrees(limit):.0f} deg) | place outside the workspace | "
        f"median larger of the view's abs roll and pitch (deg) |\n"
        "| --- | --- | --- | --- | --- | --- | --- |"
    )
    summary = []
    for path in args.records:
        record = json.loads(path.read_text())
        if record.get("method") != "mira":
            print(f"{path} is not a mira record (method {record.get('method')})", file=sys.stderr)
            return 1
        counts = place_view_summary(record, limit)
        print(
            f"| {path} | {counts['setting']} | {counts['episodes']} | {counts['successes']} | "
            f"{counts['beyond_grid']} ({counts['beyond_grid_successes']} succeeded) | "
            f"{counts['outside_workspace']} ({counts['outside_workspace_successes']} succeeded) | "
            f"{counts['median_view_angle_deg']:.0f} |"
        )
        summary.append({"record": str(path), **counts})
    if args.json:
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
