"""The view search of `mira`, measured: where it placed against where the task asked for.

For an episode of an imagery method that reports its search (`Mira.act_with_search`), the
evaluation records `view_search`:

- `chosen_view`: (roll, pitch) of the view the place was chosen in, radians;
- `true_view`: (roll, pitch) of the grid view nearest to the target's tilt, as the training label
  chooses it (`data.labels.to_view_frames` of the oracle's place for the policy's own pick: the
  target pose x object pose^-1 x the pick);
- `true_view_rank`: the true view's rank among all views by the search's own score (0 = chosen);
- `view_steps`: grid steps between the chosen and the true view (the larger of the roll and the
  pitch steps; 0 = the true view, 1 = one of its neighbours);
- `true_view_pixel_error`: pixels between the search's best placement in the true view and the
  label's pixel there, and `true_view_rotation_error`: rotation bins between them (circular);
  None where the label falls outside the image (a pick far off the object).

`summary(records)` pools an evaluation's records into the figures logged as
`eval/view_top1`, `eval/view_within_one_step` and `eval/true_view_rank_median`.

`evaluation.view_probe` measures the same search on validation demonstrations, without a
simulator, during training.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.data.labels import labels_from_view_action, to_view_frames

VIEW_SEARCH_FIGURES = ("view_top1", "view_within_one_step", "true_view_rank_median")


def grid_step(views: np.ndarray) -> float:
    """The spacing of a (roll, pitch) view grid, radians."""
    rolls = np.unique(np.round(np.asarray(views, dtype=float)[:, 0], 9))
    return float(np.min(np.diff(rolls))) if len(rolls) > 1 else float("inf")


def view_steps(first: np.ndarray, second: np.ndarray, views: np.ndarray) -> int:
    """Grid steps between two (roll, pitch) views of the grid `views`: the larger of the roll and
    the pitch steps (0 = the same view, 1 = a neighbour)."""
    difference = np.abs(np.asarray(first, dtype=float) - np.asarray(second, dtype=float)).max()
    return int(round(float(difference / grid_step(views))))


def true_action(task: Any, env: Any, pick: g.Pose) -> dict[str, g.Pose]:
    """The oracle's action for the policy's own pick: the place that brings the object to the
    target the oracle aims for (`task.oracle_target`) when held at `pick`."""
    object_pose = task.object_pose(env)
    target = task.oracle_target(env, object_pose)
    place = g.multiply_poses(target, g.invert_pose(object_pose), pick)
    return {"pick": pick, "place": place}


def view_search_record(
    search: Any,
    truth: dict[str, g.Pose],
    views: np.ndarray,
    pixel_size: float,
    n_rotations: int,
) -> dict[str, Any]:
    """The `view_search` record of one episode (see the module docstring) from the policy's
    `PlaceSearch` and the true action for its pick."""
    views = np.asarray(views, dtype=float)
    view_action = to_view_frames(truth, views)
    chosen, true = search.chosen_view, view_action.place_view
    record = {
        "chosen_view": [float(a) for a in views[chosen]],
        "true_view": [float(a) for a in views[true]],
        "true_view_rank": search.view_rank(true),
        "view_steps": view_steps(views[chosen], views[true], views),
        "true_view_pixel_error": None,
        "true_view_rotation_error": None,
    }
    try:
        labels = labels_from_view_action(view_action, pixel_size, n_rotations)
    except ValueError:  # the label of a pick off the object can fall outside the image
        return record
    rotation, row, col = (int(v) for v in search.view_best[true])
    bins = abs(rotation - labels.rotation_bin) % n_rotations
    record["true_view_pixel_error"] = float(
        np.hypot(row - labels.place_pixel[0], col - labels.place_pixel[1])
    )
    record["true_view_rotation_error"] = int(min(bins, n_rotations - bins))
    return record


def summary(records: list[dict[str, Any] | None]) -> dict[str, float] | None:
    """`view_top1` and `view_within_one_step` (fractions of the episodes with a record) and
    `true_view_rank_median`, or None where no episode has a record."""
    kept = [record for record in records if record]
    if not kept:
        return None
    steps = np.array([record["view_steps"] for record in kept])
    ranks = np.array([record["true_view_rank"] for record in kept])
    return {
        "view_top1": float(np.mean(steps == 0)),
        "view_within_one_step": float(np.mean(steps <= 1)),
        "true_view_rank_median": float(np.median(ranks)),
        "view_search_episodes": float(len(kept)),
    }


def view_search_text(figures: dict[str, float] | None) -> str:
    """ "true view 45%, within one step 90%, median rank 1" of `summary`'s figures ("-": none)."""
    if not figures:
        return "-"
    return (
        f"true view {figures['view_top1']:.0%}, within one step "
        f"{figures['view_within_one_step']:.0%}, median rank {figures['true_view_rank_median']:g}"
    )
