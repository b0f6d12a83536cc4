"""The cell loader at its edges (the survivors of a mutation run, docs/mutation.md): cells at the
ends of the counts that are valid and must load (no errors field, an erred episode, every episode
a strict success, no episode run), the setting a policy was trained in, and a malformed field deep
in a cell refused with a message naming where it lies."""

from __future__ import annotations

import copy
import json
import re
from collections.abc import Callable
from typing import Any

import pytest

from nerf_transporter.evaluation.metrics import wilson_interval
from nerf_transporter.experiments.cells import (
    TOLERANCE,
    CellFileError,
    load_cell,
    load_record,
    trained_setting,
)
from tests.experiments.test_cell_checks import CROSS_CELL, NORMAL_CELL, _strict_count, _write

Edit = Callable[[dict[str, Any]], None]


@pytest.fixture
def cell() -> dict[str, Any]:
    """The committed Normal block-insertion cell (84/100, strict 83, no errors), to edit."""
    return json.loads(NORMAL_CELL.read_text())


def _load(tmp_path, cell: dict[str, Any]) -> dict[str, Any]:
    return load_cell(_write(tmp_path, cell, NORMAL_CELL), world=cell["world"])


def _erred_episode(cell: dict[str, Any]) -> int:
    """An erred episode on a further test seed, counted as the cell's one error."""
    seed = max(cell["test_seeds"]) + 2
    cell["test_seeds"].append(seed)
    cell["episode_results"].append(
        {"seed": seed, "success": False, "outcome": "error", "error": "RuntimeError: simulated"}
    )
    cell.update(errors=1, erred_seeds=[seed])
    return seed


@pytest.mark.parametrize("absent", [("errors",), ("errors", "erred_seeds"), ("machine",)])
def test_a_cell_written_before_errors_or_machines_were_recorded_loads(tmp_path, cell, absent):
    for key in absent:
        del cell[key]
    loaded = _load(tmp_path, cell)
    assert (loaded["successes"], loaded["episodes"], loaded.get("errors", 0)) == (84, 100, 0)


def test_an_erred_episode_counts_apart_from_the_episodes_that_ran(tmp_path, cell):
    seed = _erred_episode(cell)
    loaded = _load(tmp_path, cell)
    assert (loaded["successes"], loaded["episodes"], loaded["erred_seeds"]) == (84, 100, [seed])


def test_every_episode_a_strict_success_loads(tmp_path, cell):
    _strict_count(cell, 100)
    cell.update(successes=100, success_rate=1.0, ci_low=cell["strict_ci_low"], ci_high=1.0)
    loaded = _load(tmp_path, cell)
    assert (loaded["successes"], loaded["strict_successes"]) == (100, 100)


def test_a_cell_whose_every_episode_erred_loads_with_no_rate(tmp_path, cell):
    del cell["episode_results"], cell["test_seeds"]
    low, high = wilson_interval(0, 0)
    cell.update(episodes=0, successes=0, success_rate=None, ci_low=low, ci_high=high)
    cell.update(errors=2, erred_seeds=[1, 3], strict_successes=None, strict_success_rate=None)
    loaded = _load(tmp_path, cell)
    assert (loaded["episodes"], loaded["errors"], loaded["success_rate"]) == (0, 2, None)


def test_a_negative_error_count_is_refused(tmp_path, cell):
    del cell["episode_results"], cell["test_seeds"], cell["erred_seeds"]
    cell["errors"] = -1
    with pytest.raises(CellFileError, match=r"\(-1 erred\): counts lie in 0..episodes"):
        _load(tmp_path, cell)


def _set(path: tuple[Any, ...], value: Any) -> Edit:
    """The edit setting the field at `path` (keys and indices) of a cell to `value`."""

    def edit(cell: dict[str, Any]) -> None:
        *parents, key = path
        target = cell
        for parent in parents:
            target = target[parent]
        target[key] = value

    return edit


# the message naming where the problem lies -> the edit making it
MALFORMED: dict[str, Edit] = {
    "lacks successes": lambda cell: cell.pop("successes"),
    ": protocol: task is 3, not a string": _set(("protocol", "task"), 3),
    'its protocol\'s task is "hanging-disks", the cell\'s "block-insertion"': _set(
        ("protocol", "task"), "hanging-disks"
    ),
    'its protocol\'s setting is "challenging", the cell\'s "normal"': _set(
        ("protocol", "setting"), "challenging"
    ),
    "its protocol's imagery is \"oracle\", the cell's null": _set(
        ("protocol", "imagery"), "oracle"
    ),
    ": checkpoint: path is 3, not a string$": _set(("checkpoint", "path"), 3),
    ": machine: fit is {}, not a list$": _set(("machine", "fit"), {}),
    r": machine: test is \[\], not an object$": _set(("machine", "test"), []),
    r": machine.fit\[0\]: cpu is 3, not a string or null$": _set(("machine", "fit", 0, "cpu"), 3),
    r": machine.fit\[0\]: gpu is 3, not a string or null$": _set(("machine", "fit", 0, "gpu"), 3),
    r": episode_results\[0\]: seed is \"1\", not an integer": _set(
        ("episode_results", 0, "seed"), "1"
    ),
    r": its test_seeds \[\"1\", 3, .* are not seeds \(integers\)$": _set(("test_seeds", 0), "1"),
    r"episode_results\[0\]: outcome \"failure\" is not success \(success true, error null; "
    r"outcomes: success, failure, error\)": _set(("episode_results", 0, "outcome"), "failure"),
}


@pytest.mark.parametrize("problem", list(MALFORMED))
def test_a_malformed_field_is_refused_naming_where_it_lies(tmp_path, cell, problem):
    MALFORMED[problem](cell)
    path = _write(tmp_path, cell, NORMAL_CELL)
    with pytest.raises(CellFileError, match=problem) as refused:
        load_cell(path, world=cell["world"])
    assert str(refused.value).startswith(str(path))


def test_an_erred_episode_of_another_outcome_is_refused_naming_its_error(tmp_path, cell):
    _erred_episode(cell)
    cell["episode_results"][-1]["outcome"] = "failure"
    with pytest.raises(CellFileError, match=r"is not error \(success false, error \"Runtime"):
        _load(tmp_path, cell)


@pytest.mark.parametrize("record", [[1, 2], "cell"])
def test_a_file_holding_no_object_is_refused_naming_what_it_holds(tmp_path, record):
    path = tmp_path / "cell.json"
    path.write_text(json.dumps(record))
    with pytest.raises(
        CellFileError,
        match=f"^{re.escape(str(path))} is {re.escape(json.dumps(record))}, not an object$",
    ):
        load_record(path)


def test_a_test_record_is_no_cell(tmp_path, cell):
    del cell["protocol"]
    path = _write(tmp_path, cell, NORMAL_CELL)
    with pytest.raises(CellFileError, match=r"is not a cell of run-cell \(no protocol\)$"):
        load_cell(path, world=cell["world"])


def test_the_trained_setting_is_the_protocols_then_the_records_then_the_tested_one():
    record = {"setting": "challenging"}
    assert trained_setting(record) == "challenging"
    assert trained_setting(record | {"protocol": None, "trained_setting": "flat"}) == "flat"
    protocol = {"trained_setting": "normal"}
    assert trained_setting(record | {"protocol": protocol, "trained_setting": "flat"}) == "normal"
    assert trained_setting(record | {"protocol": protocol}) == "normal"
    assert trained_setting(copy.deepcopy(record) | {"protocol": {}}) == "challenging"


def test_counts_stored_within_the_tolerance_of_the_recomputed_ones_load(tmp_path, cell):
    """A rate or interval a hair (within `TOLERANCE`) from what the counts give is the same."""
    half = 0.95 * TOLERANCE  # beyond the relative 1e-9 of isclose
    cell.update(ci_low=cell["ci_low"] + half, ci_high=cell["ci_high"] - half)
    cell.update(success_rate=cell["success_rate"] + half)
    cell.update(strict_ci_low=cell["strict_ci_low"] - half)
    cell.update(strict_ci_high=cell["strict_ci_high"] + half)
    assert _load(tmp_path, cell)["successes"] == 84


def test_a_record_of_another_split_is_refused_naming_it(tmp_path, cell):
    cell["split"] = "validation"
    with pytest.raises(CellFileError, match='nor a test record: its split is "validation"$'):
        _load(tmp_path, cell)


def test_many_repeated_seeds_are_listed_five_and_counted(tmp_path, cell):
    cell["test_seeds"][:14] = [seed for seed in range(1, 14, 2) for _ in range(2)]  # 7 twice
    with pytest.raises(CellFileError, match="list seed 1, 3, 5, 7, 9 and 2 more more than once"):
        _load(tmp_path, cell)


def test_a_validation_rate_above_one_is_refused(tmp_path, cell):
    cell["validation"][0]["success_rate"] = 1.5
    with pytest.raises(CellFileError, match=r"validation\[0\]: success_rate 1.5 is no success"):
        _load(tmp_path, cell)


def test_a_count_of_two_to_the_53_is_the_largest_a_record_holds(tmp_path, cell):
    cell["checkpoint"]["step"] = 2**53
    assert _load(tmp_path, cell)["checkpoint"]["step"] == 2**53
    cell["checkpoint"]["step"] = 2**53 + 1
    with pytest.raises(CellFileError, match="step is 9007199254740993, not an integer of at most"):
        _load(tmp_path, cell)


def test_a_cross_setting_cell_lacking_its_fit_protocol_id_is_refused(tmp_path):
    cell = json.loads(CROSS_CELL.read_text())
    del cell["protocol"]["fit_protocol_id"]
    path = _write(tmp_path, cell, CROSS_CELL)
    with pytest.raises(
        CellFileError, match="needs trained_setting, fit_protocol_id in its protocol"
    ):
        load_cell(path, world=cell["world"])


def test_a_record_is_checked_against_the_world_it_is_asked_for(tmp_path, cell):
    path = _write(tmp_path, cell, NORMAL_CELL)
    with pytest.raises(CellFileError, match=f"measured in world {cell['world']}"):
        load_record(path, world="0123456789abcdef")
