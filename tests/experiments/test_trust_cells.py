"""Well-formed cells that would state a wrong number are refused by the cell loader, naming the
file: repeated or training seeds, another confidence than the tables', a validation rate that is
no rate, a task, setting, method or imagery this package does not have, and counts or nesting no
number or table can hold. `report` and `compare-cells` exit 2 on them, without a traceback."""

from pathlib import Path

import pytest

from nerf_transporter.experiments import compare, report
from nerf_transporter.experiments.cells import METHOD_NAMES, CellFileError, load_record
from nerf_transporter.methods import METHODS
from tests.experiments.test_compare import edited, write_cell

REPO = Path(__file__).resolve().parents[2]
ODD = dict.fromkeys(range(1, 41, 2), True)  # 20 successful episodes on the first test seeds


def assert_refused(path, problem):
    """`load_record` refuses `path`, naming it and `problem`."""
    with pytest.raises(CellFileError) as raised:
        load_record(path)
    assert str(raised.value).startswith(str(path)) and problem in str(raised.value), raised.value


def cell_with_episodes(folder, outcomes):
    """A cell whose episode records are `outcomes` ((seed, success) pairs, seeds as given), its
    counts, rate and interval those of the pairs."""
    unique = {index * 2 + 1: won for index, (_, won) in enumerate(outcomes)}
    path = write_cell(folder, "mira", unique)
    return edited(
        path,
        lambda record: [
            episode.update(seed=seed)
            for episode, (seed, _) in zip(record["episode_results"], outcomes, strict=True)
        ],
    )


@pytest.mark.parametrize(
    ("outcomes", "problem"),
    [
        ([(1, True)] * 100, "list seed 1 more than once: a test seed is one episode"),
        ([(1, True), (1, False), (3, True)], "list seed 1 more than once"),
        ([(0, True), (2, True), (5, False)], "hold seeds of no test episode: 0 (train), 2 (train)"),
        ([(1_000_001, True)], "hold seeds of no test episode: 1000001 (validation)"),
        ([(-1, True)], "hold seeds of no test episode: -1 (negative)"),
    ],
    ids=["one-seed-100-times", "one-seed-twice", "training-seeds", "validation-seed", "negative"],
)
def test_a_cell_is_tested_on_distinct_test_seeds(tmp_path, capsys, outcomes, problem):
    """100 copies of one successful seed would read 100% (100, 96-100); even seeds trained it."""
    folder = tmp_path / "results" / "block-insertion"
    folder.mkdir(parents=True)
    path = cell_with_episodes(folder, outcomes)
    assert_refused(path, f"its episode_results {problem}")
    assert report.main([str(tmp_path / "results")]) == 2
    assert problem in capsys.readouterr().err


def test_a_cells_test_seeds_are_its_episodes_seeds(tmp_path):
    path = write_cell(tmp_path, "cell", {1: True, 3: False, 5: None})
    test_seeds = [1, 3, 5]
    edited(path, lambda record: record.update(test_seeds=test_seeds))
    assert load_record(path)["test_seeds"] == test_seeds
    cases = [
        ([1, 3, 7], "test_seeds are not the seeds of its episode_results"),
        ([1, 3], "its 2 test_seeds are not its 2 episodes and 1 erred ones"),
        ([1, 1, 3], "its test_seeds list seed 1 more than once"),
        ([1, 3, 4], "its test_seeds hold seeds of no test episode: 4 (train)"),
    ]
    for seeds, problem in cases:
        edited(path, lambda record, seeds=seeds: record.update(test_seeds=seeds))
        assert_refused(path, problem)
    edited(path, lambda record: record.update(test_seeds=[1, 3, 5], erred_seeds=[3]))
    assert_refused(path, "erred_seeds [3] are not the seeds of its erred episodes [5]")


def test_compare_cells_refuses_other_seed_sets_unless_asked_and_says_what_it_paired(
    tmp_path, capsys
):
    first = write_cell(tmp_path, "first", ODD)
    other = write_cell(tmp_path, "other", dict.fromkeys(range(1, 21, 2), False))
    assert compare.main([str(first), str(other)]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"nerf-transporter compare-cells: {other} was tested on 10 seeds, {first} on 20, 10 of "
        "them common: pass --allow-unequal-seeds to pair them on the common seeds\n"
    )
    assert compare.main([str(first), str(other), "--allow-unequal-seeds"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[-1] == (
        f"{other}: paired on 10 seeds: the 10 both were tested on (this one 10, the first 20), "
        "less 0 that erred in either"
    )
    same = write_cell(tmp_path, "same", ODD | {1: None})
    assert compare.main([str(first), str(same)]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        f"{same}: paired on 19 seeds: the 20 both were tested on (this one 20, the first 20), "
        "less 1 that erred in either"
    )


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (
            lambda r: r.update(confidence=0.5),
            "confidence 0.5 is not 0.95, the confidence of every interval the tables state",
        ),
        (
            lambda r: r.update(validation=[{"step": 500, "success_rate": 5.0}]),
            "validation[0]: success_rate 5.0 is no success rate",
        ),
        (
            lambda r: (
                r.update(validation=[{"step": 500, "success_rate": 0.33}])
                or r["protocol"].update(validation_episodes=20)
            ),
            "validation[0]: success_rate 0.33 is no success rate of 20 episodes",
        ),
        (
            lambda r: (
                r.update(task="tower-of-hanoi") or r["protocol"].update(task="tower-of-hanoi")
            ),
            'task "tower-of-hanoi" is none of this package\'s',
        ),
        (
            lambda r: r.update(method="magic") or r["protocol"].update(method="magic"),
            'method "magic" is none of this package\'s (mira, transporter_se2',
        ),
        (
            lambda r: (
                r.update(setting="upside-down") or r["protocol"].update(setting="upside-down")
            ),
            'setting "upside-down" is none of this package\'s (normal, challenging, flat)',
        ),
        (
            lambda r: r.update(imagery="sketch") or r["protocol"].update(imagery="sketch"),
            'imagery "sketch" is none of this package\'s (None, nerf, oracle)',
        ),
        (
            lambda r: r["protocol"].update(trained_setting="sideways"),
            'protocol: trained_setting "sideways" is none of this package\'s',
        ),
        (
            lambda r: r.update(episodes=10**400),
            "episodes is 1000000000000000000000000000000000000000",
        ),
        (lambda r: r.update(ci_low=10**400), "ci_low is 1000000000000000000000000000000000000000"),
    ],
    ids=[
        "confidence",
        "validation-rate-5",
        "validation-rate-of-no-count",
        "unknown-task",
        "unknown-method",
        "unknown-setting",
        "unknown-imagery",
        "unknown-trained-setting",
        "episodes-10**400",
        "interval-10**400",
    ],
)
def test_a_well_formed_cell_of_a_wrong_number_is_refused_by_name(tmp_path, capsys, edit, problem):
    """Each would render: under the 95% Wilson heading, as 100/20 in the validation table, as a
    column or row of its own, or as a float overflow traceback."""
    folder = tmp_path / "results" / "block-insertion"
    folder.mkdir(parents=True)
    path = edited(write_cell(folder, "mira", ODD), edit)
    assert_refused(path, problem)
    assert report.main([str(tmp_path / "results")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nerf-transporter report: {path}") and len(err.splitlines()) == 1
    other = write_cell(tmp_path, "other", ODD)
    assert compare.main([str(other), str(path)]) == 2
    assert capsys.readouterr().err.startswith(f"nerf-transporter compare-cells: {path}")


@pytest.mark.parametrize(
    "text",
    ["[" * 100_000 + "]" * 100_000, '{"episodes": 1' + "0" * 5000 + "}"],
    ids=["nested-100000-deep", "integer-of-5001-digits"],
)
def test_a_file_no_parser_reads_is_named(tmp_path, capsys, text):
    folder = tmp_path / "results" / "block-insertion"
    folder.mkdir(parents=True)
    path = folder / "mira.json"
    path.write_text(text)
    assert report.main([str(tmp_path / "results")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nerf-transporter report: unreadable results file {path}: ")
    other = write_cell(tmp_path, "other", ODD)
    assert compare.main([str(other), str(path)]) == 2
    assert f"unreadable results file {path}" in capsys.readouterr().err


def test_the_loaders_method_names_are_the_methods():
    assert sorted(METHOD_NAMES) == sorted(METHODS)


def test_every_cell_and_test_record_under_results_still_loads():
    paths = sorted((REPO / "results").rglob("*.json"))
    assert len(paths) >= 54
    for path in paths:
        load_record(path)
