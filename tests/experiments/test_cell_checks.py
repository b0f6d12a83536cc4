"""Each of the cell loader's cross-checks, one at a time: a committed cell edited so that exactly
one check is violated (every other check still passes) is refused with a message naming that
problem. Deleting any one check from `evaluation/cells.py` fails the case that names it: the file
then loads, or is refused by another check with another message."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from nerf_transporter.evaluation.metrics import wilson_interval
from nerf_transporter.experiments.cells import CellFileError, load_cell

RESULTS = Path(__file__).resolve().parents[2] / "results"
NORMAL_CELL = RESULTS / "block-insertion" / "transporter_se2.json"  # 84/100, strict 83
CROSS_CELL = RESULTS / "block-insertion-challenging" / "transporter_se2.json"  # trained Normal

Edit = Callable[[dict[str, Any]], None]


def _flip_first_success(cell: dict[str, Any]) -> None:
    """One successful episode recorded as a failure; the cell's counts left as they were."""
    episode = next(episode for episode in cell["episode_results"] if episode["success"])
    episode.update(success=False, outcome="failure", strict_success=False)


def _add_an_erred_episode(cell: dict[str, Any]) -> None:
    """An erred episode on a further seed (in test_seeds too); the cell's errors (0) left as
    they were."""
    seed = max(cell["test_seeds"]) + 2
    cell["test_seeds"].append(seed)
    cell["episode_results"].append(
        {"seed": seed, "success": False, "outcome": "error", "error": "RuntimeError: simulated"}
    )


def _strict_count(cell: dict[str, Any], strict: int) -> None:
    """The strict count set to `strict`, its rate and interval those of the new count, and the
    episodes (which would count the old one) dropped."""
    del cell["episode_results"], cell["test_seeds"]
    low, high = wilson_interval(min(max(strict, 0), cell["episodes"]), cell["episodes"])
    cell.update(
        strict_successes=strict,
        strict_success_rate=strict / cell["episodes"],
        strict_ci_low=low,
        strict_ci_high=high,
    )


def _successes(cell: dict[str, Any], successes: int) -> None:
    """The success count set to `successes` with its rate and interval, episodes dropped."""
    del cell["episode_results"], cell["test_seeds"]
    cell.update(successes=successes, success_rate=successes / cell["episodes"])
    if 0 <= successes <= cell["episodes"]:
        cell["ci_low"], cell["ci_high"] = wilson_interval(successes, cell["episodes"])


# problem named in the message -> the edit of the Normal cell that violates only that check
NORMAL_EDITS: dict[str, Edit] = {
    "successes is 84, its episodes hold 83": _flip_first_success,
    # the seed count against the episodes and errors stated, checked before the counts themselves
    "its 101 test_seeds are not its 100 episodes and 0 erred ones": _add_an_erred_episode,
    "strict_successes is 83, its episodes hold 82": lambda cell: next(
        episode for episode in cell["episode_results"] if episode["strict_success"]
    ).update(strict_success=False),
    "test_seeds are not the seeds of its episode_results": lambda cell: cell[
        "test_seeds"
    ].reverse(),
    r"erred_seeds \[7\] are not the 0 erred": lambda cell: cell.update(erred_seeds=[7]),
    "success_rate 0.85 is not 84 of 100": lambda cell: cell.update(success_rate=0.85),
    "strict_success_rate 0.84 is not 83 of 100": lambda cell: cell.update(strict_success_rate=0.84),
    "101 successes of 100 episodes": lambda cell: _successes(cell, 101),
    "101 strict successes of 100 episodes": lambda cell: _strict_count(cell, 101),
    "-1 strict successes of 100 episodes": lambda cell: _strict_count(cell, -1),
    "ci_low-ci_high 0.75-": lambda cell: cell.update(ci_low=0.75),
    "strict_ci_low-strict_ci_high 0.74-": lambda cell: cell.update(strict_ci_low=0.74),
    "confidence 1.5 is not 0.95": lambda cell: cell.update(confidence=1.5),
    "confidence 0 is not 0.95": lambda cell: cell.update(confidence=0),
    "names a fit, but its protocol has no trained_setting": lambda cell: cell.update(
        fit={"protocol_id": cell["protocol_id"], "run_dir": "x", "checkpoint": "y"}
    ),
    r"overlays \[3\] are not config paths": lambda cell: cell.update(overlays=[3]),
    r"machine.fit\[0\]: cpu is 3, not": lambda cell: cell["machine"]["fit"][0].update(cpu=3),
    'outcome "failure" is not success': lambda cell: cell["episode_results"][0].update(
        outcome="failure"
    ),
    'its protocol\'s method is "mira"': lambda cell: cell["protocol"].update(method="mira"),
    "episodes is 100.0, not an integer": lambda cell: cell.update(episodes=100.0),
    "strict_successes is true, not an integer": lambda cell: cell.update(strict_successes=True),
}


def _write(tmp_path: Path, cell: dict[str, Any], source: Path) -> Path:
    path = tmp_path / source.parent.name / source.name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(cell))
    return path


@pytest.fixture(scope="module")
def normal_cell() -> dict[str, Any]:
    return json.loads(NORMAL_CELL.read_text())


def test_the_committed_cells_used_here_load_unedited(tmp_path, normal_cell):
    """The edits below start from valid cells: any refusal is the edit's."""
    for source, cell in (
        (NORMAL_CELL, normal_cell),
        (CROSS_CELL, json.loads(CROSS_CELL.read_text())),
    ):
        loaded = load_cell(_write(tmp_path, cell, source), world=cell["world"])
        assert (loaded["successes"], loaded["episodes"]) == (cell["successes"], 100)
    assert (normal_cell["successes"], normal_cell["strict_successes"]) == (84, 83)
    assert normal_cell["errors"] == 0 and normal_cell["confidence"] == 0.95


@pytest.mark.parametrize("problem", list(NORMAL_EDITS))
def test_a_cell_violating_one_check_is_refused_naming_it(tmp_path, normal_cell, problem):
    cell = copy.deepcopy(normal_cell)
    NORMAL_EDITS[problem](cell)
    path = _write(tmp_path, cell, NORMAL_CELL)
    with pytest.raises(CellFileError, match=problem) as refused:
        load_cell(path, world=cell["world"])
    assert str(path) in str(refused.value)


def test_a_cell_measured_in_another_world_is_refused_naming_both(tmp_path, normal_cell):
    path = _write(tmp_path, normal_cell, NORMAL_CELL)
    with pytest.raises(CellFileError, match=f"measured in world {normal_cell['world']}"):
        load_cell(path, world="0123456789abcdef")
