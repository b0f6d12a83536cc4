"""`nerf-transporter report`: the results table from results.json files."""

import json
from pathlib import Path

import cv2
import pytest

from nerf_transporter.cli import main as cli_main
from nerf_transporter.data.observation import SceneSpec
from nerf_transporter.evaluation.metrics import wilson_interval
from nerf_transporter.experiments.cells import column_folder, cross_protocol
from nerf_transporter.experiments.report import (
    README_END,
    README_START,
    RESULTS_DOC_END,
    RESULTS_DOC_START,
    table_plot,
)
from nerf_transporter.experiments.report import main as report_main
from nerf_transporter.sim.fingerprint import world_fingerprint


def _write(root, run, method, task, setting, successes, episodes, created, name=None, trained=None):
    """A test record as `lightning test` writes it (the fields the report reads; without the
    setting trained in unless `trained`, as records written before it was recorded)."""
    path = root / run / "checkpoints" / (name or "results.json")
    path.parent.mkdir(parents=True)
    low, high = wilson_interval(successes, episodes)
    record = {
        "method": method,
        "task": task,
        "setting": setting,
        "split": "test",
        "world": world_fingerprint(),
        "episodes": episodes,
        "successes": successes,
        "success_rate": successes / episodes,
        "ci_low": low,
        "ci_high": high,
        "created": created,
    }
    path.write_text(json.dumps(record | ({"trained_setting": trained} if trained else {})))


@pytest.fixture
def logs(tmp_path):
    root = tmp_path / "logs"
    _write(
        root,
        "bi/mira/version_0",
        "mira",
        "block-insertion",
        "normal",
        3,
        20,
        "2024-01-01T00:00:00",
    )
    # a newer run of the same cell replaces the older one
    _write(
        root,
        "bi/mira/version_1",
        "mira",
        "block-insertion",
        "normal",
        16,
        20,
        "2024-01-02T00:00:00",
    )
    _write(
        root,
        "bi/se2/version_0",
        "transporter_se2",
        "block-insertion",
        "normal",
        5,
        20,
        "2024-01-01T00:00:00",
    )
    _write(
        root,
        "prg/mira/version_0",
        "mira",
        "place-red-in-green",
        "challenging",
        50,
        100,
        "2024-01-01T00:00:00",
        name="results-challenging.json",  # a Normal-trained model tested in Challenging
        trained="normal",
    )
    _write(
        root,
        "bi-flat/se2/version_0",
        "transporter_se2",
        "block-insertion",
        "flat",
        20,
        20,
        "2024-01-01T00:00:00",
    )
    return root


EXPECTED = """\
| method | block-insertion | block-insertion Challenging | place-red-in-green | place-red-in-green Challenging | hanging-disks | hanging-disks Challenging | stacking-kits | stacking-kits Challenging | block-insertion Flat (trained Flat) |
| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |
| mira (ours) | 80% (20, 58-92) / - |  |  | 50% (100, 40-60) / - |  |  |  |  |  |
| paper: its method | 80% |  | 86% | 50% | 40% |  | 32% |  |  |
| mira, oracle imagery |  |  |  |  |  |  |  |  |  |
| Transporter-SE(2) | 25% (20, 11-47) / - |  |  |  |  |  |  |  | 100% (20, 84-100) / - |
| paper: Transporter-SE(2) | 21% |  | 74% | 18% | 32% |  | 18% |  |  |
| Transporter-SE(3) |  |  |  |  |  |  |  |  |  |
| paper: Transporter-SE(3) | 20% |  | 77% | 20% | 32% |  | 16% |  |  |
| Form2Fit |  |  |  |  |  |  |  |  |  |
| paper: Form2Fit | 0% |  | 79% | 30% | 1% |  | 4% |  |  |
| GT-State MLP |  |  |  |  |  |  |  |  |  |
| paper: GT-State MLP | 0% |  | 1% | 1% | 0% |  | 0% |  |  |
"""


def test_report_renders_the_markdown_table(logs, capsys):
    assert cli_main(["report", str(logs)]) == 0
    assert capsys.readouterr().out == EXPECTED


def test_report_csv(logs, capsys):
    assert report_main([str(logs), "--csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == (
        "method,block-insertion,block-insertion Challenging,place-red-in-green,"
        "place-red-in-green Challenging,hanging-disks,hanging-disks Challenging,stacking-kits,"
        "stacking-kits Challenging,block-insertion Flat (trained Flat)"
    )
    assert lines[4] == 'Transporter-SE(2),"25% (20, 11-47) / -",,,,,,,,"100% (20, 84-100) / -"'


CPU = {"cpu": "AMD EPYC", "threads": 1, "gpu": None}


def write_cell(
    root,
    row,
    task,
    setting,
    successes,
    episodes,
    imagery=None,
    validation=None,
    overlays=(),
    fit=CPU,
    trained=None,
    strict=None,
    won=None,
    reference_imagery=False,
):
    """A cell as run-cell writes it (the fields the report reads, its protocol and overlays),
    trained in `trained` (default: the setting it is tested in; another: a cross-setting cell
    naming its fit), with `strict` strict 6-DoF successes where given, and, where `won` is given,
    its episodes: test seeds 1, 3, 5, ..., the `won`-th of them (counted from 0) succeeded. A
    NeRF-imagery cell read the default imagery, or the reference imagery where
    `reference_imagery` (a cell fitted before the default changed: no `imagery_changes`)."""
    trained = trained or setting
    column = column_folder(task, setting, trained)
    low, high = wilson_interval(successes, episodes)
    method = row.removesuffix("-oracle")
    protocol = {"task": task, "setting": trained, "method": method, "imagery": imagery}
    if imagery == "nerf" and not reference_imagery:
        protocol["imagery_changes"] = SceneSpec(task, imagery="nerf").imagery_changes()
    protocol |= {"steps": 2000, "batch_size": 1, "lr": 1e-4, "validation_every": 500}
    protocol |= {"validation_episodes": 10, "test_episodes": episodes}
    checkpoint = {"step": 2000, "path": "logs/cells/run/version_0/checkpoints/step002000.ckpt"}
    extra = {}
    if trained != setting:
        protocol = cross_protocol(protocol, setting)
        fit_run = {"protocol_id": protocol["fit_protocol_id"], "run_dir": "logs/cells/run"}
        extra["fit"] = fit_run | {"checkpoint": checkpoint["path"]}
    if strict is not None:
        strict_low, strict_high = wilson_interval(strict, episodes)
        extra |= {"strict_successes": strict, "strict_ci_low": strict_low}
        extra |= {"strict_ci_high": strict_high}
    record = extra | {
        "protocol": protocol,
        "world": world_fingerprint(),
        "checkpoint": checkpoint,
        "validation": [{"step": step, "success_rate": rate} for step, rate in validation or ()],
        "task": task,
        "setting": setting,
        "method": method,
        "imagery": imagery,
        "episodes": episodes,
        "successes": successes,
        "ci_low": low,
        "ci_high": high,
        "errors": 0,
        "overlays": list(overlays),
        "machine": {"fit": [fit], "test": CPU},
        "created": "2026-11-25T00:00:00+00:00",
    }
    if won is not None:
        record["episode_results"] = [
            {"seed": 2 * index + 1, "success": index in won} for index in range(episodes)
        ]
    path = root / column / f"{row}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record))


def _docs(tmp_path):
    """A README and a results page, each with its results block and text around it."""
    readme, results_doc = tmp_path / "README.md", tmp_path / "docs" / "results.md"
    readme.write_text(f"# title\n\n{README_START}\nold text\n{README_END}\n\nthe rest\n")
    results_doc.parent.mkdir()
    results_doc.write_text(f"# results\n\n{RESULTS_DOC_START}\nold\n{RESULTS_DOC_END}\n\nend\n")
    return readme, results_doc


def test_cells_of_a_results_folder_fill_their_rows_the_plot_and_the_readme(tmp_path, capsys):
    results = tmp_path / "results"
    curve = [(500, 0.2), (1000, 0.5), (1500, 0.7), (2000, 0.6)]
    write_cell(
        results, "mira", "block-insertion", "normal", 81, 100, "nerf", curve, reference_imagery=True
    )
    write_cell(results, "mira-oracle", "block-insertion", "normal", 90, 100, imagery="oracle")
    width64 = ["configs/gpu/width64.yaml"]
    h100 = {"cpu": "Intel(R) Xeon(R) Processor", "gpu": "NVIDIA H100 80GB HBM3"}
    write_cell(
        results,
        "form2fit",
        "place-red-in-green",
        "challenging",
        30,
        100,
        overlays=width64,
        fit=h100,
    )
    readme, results_doc = _docs(tmp_path)
    plot = tmp_path / "results" / "table1.png"
    argv = [str(results), "--readme", str(readme), "--results-doc", str(results_doc)]
    assert report_main(argv + ["--plot", str(plot)]) == 0
    rows = capsys.readouterr().out.splitlines()[2:]
    # mira's NeRF cell names no imagery changes: the reference imagery, not the default, marked
    assert rows[0].startswith("| mira (ours) | 81% (100, 72-87) / - † |  |")
    assert rows[2].startswith("| mira, oracle imagery | 90% (100, 83-94) / - |  |")
    # Form2Fit, place-red-in-green trained and tested Challenging: the optional ninth column
    assert rows[7].endswith("|  | 30% (100, 22-40) / - |")
    text = readme.read_text()
    assert text.startswith(f"# title\n\n{README_START}\n") and text.endswith(
        f"{README_END}\n\nthe rest\n"
    )
    assert "old text" not in text and "2 of 48 cells measured" in text
    assert (
        "Beyond the 8 columns: place-red-in-green Challenging (trained Challenging), 1 of 6 cells."
        in text
    )
    assert "| mira, oracle imagery | 90% (100, 83-94) / - |" in text
    assert "![results table as bars](results/table1.png)" in text
    # the README holds the table; the machines and the commands are the results page's
    assert "[docs/results.md](docs/results.md)" in text
    assert "AMD EPYC" not in text and "run-cell --task" not in text
    page = results_doc.read_text()
    assert page.startswith(f"# results\n\n{RESULTS_DOC_START}\n") and page.endswith(
        f"{RESULTS_DOC_END}\n\nend\n"
    )
    assert "old" not in page and "2 of 48 cells measured" in page
    assert "| mira, oracle imagery | 90% (100, 83-94) / - |" in page
    assert "![results table as bars](../results/table1.png)" in page
    assert "[Citation](../README.md#citation)" in page
    text = page
    assert (
        "- AMD EPYC (2 cells): mira (ours) on block-insertion; mira, oracle imagery on "
        "block-insertion\n- NVIDIA H100 80GB HBM3 (1 cell): Form2Fit on place-red-in-green "
        "Challenging (trained Challenging)\n"
    ) in text
    budget = "--steps 2000 --batch-size 1 --lr 0.0001 --val-every 500 --val-episodes 10"
    # mira's NeRF cell, of the reference imagery (its protocol names no imagery_changes), is
    # measured again with the overlay that takes that imagery back: the default is another
    assert (
        f"    nerf-transporter run-cell --task block-insertion --method mira {budget} "
        "--episodes 100 --config configs/imagery/reference.yaml --force\n"
        f"    nerf-transporter run-cell --task block-insertion --method mira --imagery oracle "
        f"{budget} --episodes 100 --force\n"
        f"    nerf-transporter run-cell --task place-red-in-green --setting challenging "
        f"--method form2fit {budget} --episodes 100 --config configs/gpu/width64.yaml --force\n"
    ) in text
    image = cv2.cvtColor(cv2.imread(str(plot)), cv2.COLOR_BGR2RGB)
    empty = table_plot([])
    # the ninth column holds a record, so the plot draws it as a ninth group beside the eight
    group = (empty.shape[1] - 80) // 8
    assert image.shape == (empty.shape[0], empty.shape[1] + group, 3)
    # mira's colour (its legend square) fills a bar below the legend, where nothing measured has none
    mira = empty[51, 67]
    assert (image[70:] == mira).all(axis=2).sum() > 1000
    assert (empty[70:] == mira).all(axis=2).sum() == 0
    # the ninth group's one bar is Form2Fit's: the fifth colour of the legend's squares
    legend = [tuple(c) for c in image[51] if int(c.max()) - int(c.min()) > 40]
    ninth = image[70:, 60 + 8 * group :]
    filled = [(ninth == colour).all(axis=2).sum() for colour in dict.fromkeys(legend)]
    assert filled[4] > 1000 and sum(filled) == filled[4]


def test_an_empty_results_folder_gives_the_paper_rows_and_says_what_to_run(tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text(f"{README_START}\n{README_END}\n")
    assert report_main([str(tmp_path), "--readme", str(readme)]) == 0
    captured = capsys.readouterr()
    assert "run-cell" in captured.err and "lightning test" in captured.err
    assert "| paper: its method | 80% |  | 86% | 50% | 40% |  | 32% |  |" in captured.out
    assert "| mira (ours) |  |  |  |  |  |  |  |  |\n" in captured.out
    text = readme.read_text()
    assert "no cell has been measured yet" in text and "table1.png" not in text
    write_cell(tmp_path, "form2fit", "place-red-in-green", "challenging", 13, 100)
    assert report_main([str(tmp_path), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert "no cell has been measured yet" in text and (
        "Beyond the 8 columns: place-red-in-green Challenging (trained Challenging), 1 of 6 cells."
        in text
    )


def test_report_names_a_readme_without_markers_and_a_missing_folder(tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text("# no markers\n")
    assert report_main([str(tmp_path), "--readme", str(readme)]) == 2
    assert f"{readme}: no results block: put the lines {README_START}" in capsys.readouterr().err
    assert readme.read_text() == "# no markers\n"
    # a results page without its markers: neither file is written, the page is named
    readme.write_text(f"{README_START}\nold\n{README_END}\n")
    page = tmp_path / "results.md"
    page.write_text(f"{README_START}\n{README_END}\n")  # the README's markers, not the page's
    assert report_main([str(tmp_path), "--readme", str(readme), "--results-doc", str(page)]) == 2
    assert f"{page}: no results block: put the lines {RESULTS_DOC_START}" in (
        capsys.readouterr().err
    )
    assert readme.read_text() == f"{README_START}\nold\n{README_END}\n"
    assert report_main([str(tmp_path / "missing")]) == 2
    assert "no such directory" in capsys.readouterr().err


def test_report_names_a_corrupt_results_file(logs, capsys):
    bad = logs / "bi/mira/version_1/checkpoints/results.json"
    bad.write_text("{not json")
    assert report_main([str(logs)]) == 2
    assert str(bad) in capsys.readouterr().err


def test_validation_plots_and_tables_hold_each_cell_with_rounds(tmp_path, capsys):
    results = tmp_path / "results"
    write_cell(
        results, "mira", "block-insertion", "normal", 81, 100, "nerf", [(500, 0.2), (1000, 1.0)]
    )
    write_cell(results, "form2fit", "block-insertion", "normal", 30, 100)  # no rounds: no line
    docs = tmp_path / "docs"
    assert report_main([str(results), "--validation-plots", str(docs), "--validation-tables"]) == 0
    tables = capsys.readouterr().out.split("\n\n", 1)[1]
    assert tables == (
        "| block-insertion | step 500 | step 1000 | test | checkpoint step | fitted on |\n"
        "| --- | --- | --- | --- | --- | --- |\n"
        "| mira (ours) | 2/10 | 10/10 | 81% (100, 72-87) | 2000 | AMD EPYC |\n"
    )
    assert [path.name for path in docs.iterdir()] == ["validation-block-insertion.png"]
    image = cv2.cvtColor(
        cv2.imread(str(docs / "validation-block-insertion.png")), cv2.COLOR_BGR2RGB
    )
    mira = image[51, 67]  # the legend's one swatch
    drawn = (image[70:] == mira).all(axis=2)
    rows, cols = drawn.nonzero()
    # the line rises from 20% at step 500 (mid-plot) to 100% at the right end
    assert cols.min() > image.shape[1] * 0.4 and cols.max() > image.shape[1] * 0.9
    assert rows[cols.argmax()] < rows[cols.argmin()]


REPO = Path(__file__).resolve().parents[2]
# a real cell, copied: the archived world's block-insertion mira cell (77 of 100)
REAL_CELL = (
    REPO / "results" / "archive" / "world-cebd2134fda05fac" / "block-insertion" / "mira.json"
)


def real_cell(root, world=None, **edits):
    """A copy of a real cell at its place under `root`, measured in `world` (default: this
    checkout's), with `edits` over its fields; returns its path."""
    record = json.loads(REAL_CELL.read_text()) | {"world": world or world_fingerprint()}
    path = root / "block-insertion" / "mira.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record | edits))
    return path


def edited_episode(root, **edits):
    """The real cell with `edits` over its first episode record."""
    record = json.loads(REAL_CELL.read_text())
    record["episode_results"][0] |= edits
    return real_cell(root, episode_results=record["episode_results"])


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda root: real_cell(root, successes=99), "is not the 95% Wilson interval of 99 of 100"),
        (lambda root: real_cell(root, successes=150), "150 successes of 100 episodes"),
        (lambda root: real_cell(root, episodes=-5), "77 successes of -5 episodes"),
        (lambda root: real_cell(root, successes="77"), 'successes is "77", not an integer'),
        (lambda root: real_cell(root, protocol=None), "protocol is null, not an object"),
        (lambda root: real_cell(root, task=["block-insertion"]), 'task is ["block-insertion"]'),
        (lambda root: edited_episode(root, success="False"), 'success is "False", not true or'),
        (lambda root: edited_episode(root, outcome="won"), 'outcome "won" is not success'),
        (lambda root: edited_episode(root, strict_success="yes"), 'strict_success is "yes"'),
        (lambda root: real_cell(root, ci_low=0.5), "is not the 95% Wilson interval of 77 of 100"),
    ],
    ids=[
        "successes-99",
        "successes-150",
        "episodes-negative",
        "successes-string",
        "protocol-null",
        "task-list",
        "success-string",
        "outcome-unknown",
        "strict-string",
        "interval",
    ],
)
def test_report_refuses_an_edited_cell_by_name(tmp_path, capsys, edit, problem):
    path = edit(tmp_path / "results")
    assert report_main([str(tmp_path / "results")]) == 2
    err = capsys.readouterr().err
    assert f"nerf-transporter report: {path}" in err and problem in err, err


def test_report_refuses_a_null_cell_and_a_cell_of_another_world_naming_both_worlds(
    tmp_path, capsys
):
    results = tmp_path / "results"
    path = real_cell(results, world="deadbeefdeadbeef", successes=99)
    assert report_main([str(results)]) == 2
    err = capsys.readouterr().err
    assert f"{path} was measured in world deadbeefdeadbeef" in err
    assert f"this checkout's world is {world_fingerprint()}" in err
    path.write_text("null")
    assert report_main([str(results)]) == 2
    assert f"{path} is null, not an object" in capsys.readouterr().err


def test_a_test_record_under_a_folder_of_cells_is_never_taken_for_a_cell(tmp_path, capsys):
    results = tmp_path / "results"
    real_cell(results)
    stray = results / "block-insertion" / "results-step000002.json"  # newer, 2 episodes
    _write(results, "block-insertion", "mira", "block-insertion", "normal", 2, 2, "2099-01-01")
    (results / "block-insertion" / "checkpoints" / "results.json").rename(stray)
    _write(results, "hanging-disks", "form2fit", "hanging-disks", "normal", 2, 2, "2099-01-01")
    assert report_main([str(results)]) == 0
    out, err = capsys.readouterr()
    assert "| mira (ours) | 77% (100, 68-84) / - † |" in out
    assert "| Form2Fit |  |  |  |" in out  # its stray test record is no cell either
    assert "left out 2 test record(s)" in err and str(stray) in err
    misplaced = results / "block-insertion" / "form2fit.json"
    (results / "block-insertion" / "mira.json").rename(misplaced)
    assert report_main([str(results)]) == 2
    assert f"{misplaced} holds the cell block-insertion/mira.json" in capsys.readouterr().err


def test_an_archived_world_renders_under_its_own_heading_never_in_the_table(tmp_path, capsys):
    results, old = tmp_path / "results", "0123456789abcdef"
    write_cell(results, "form2fit", "hanging-disks", "normal", 9, 100)
    archive = results / "archive" / f"world-{old}"
    real_cell(archive, world=old)
    readme, results_doc = _docs(tmp_path)
    argv = [str(results), "--readme", str(readme), "--results-doc", str(results_doc)]
    assert report_main(argv) == 0
    current, archived = capsys.readouterr().out.split(f"\nArchived world {old} ({archive}: 1 cells")
    assert "| mira (ours) |  |" in current and "9% (100, 5-16)" in current
    # an archived world's NeRF cell is not marked: its imagery is never compared with this code's
    assert "| mira (ours) | 77% (100, 68-84) / - |" in archived and "9% (100" not in archived
    measured = (
        f"1 of 48 cells measured in `results/`, in this checkout's world `{world_fingerprint()}`"
    )
    text = readme.read_text()
    assert measured in text and old not in text and "77% (100, 68-84)" not in text
    # the results page names the archive and where it lies, never mixing its cells in
    page = results_doc.read_text()
    assert measured in page and "77% (100, 68-84)" not in page
    assert f"Archived world `{old}`: 1 cells, kept in `results/archive/world-{old}/`" in page
    # the archive folder itself, and a cell of one world in another's archive
    assert report_main([str(archive)]) == 0
    assert f"Archived world {old}" in capsys.readouterr().out
    real_cell(archive, world="fedcba9876543210")
    assert report_main([str(results)]) == 2
    err = capsys.readouterr().err
    assert f"lies in the archive of world {old} but was measured in world fedcba9876543210" in err


def test_an_earlier_recipe_renders_under_its_own_heading_never_in_the_table(tmp_path, capsys):
    """The table refitted under a new training recipe keeps the cells of the old one, this world's,
    under `archive/recipe-<name>/`: shown apart, checked as this world's cells."""
    results = tmp_path / "results"
    write_cell(results, "form2fit", "hanging-disks", "normal", 9, 100)
    archive = results / "archive" / "recipe-2026-12-03"
    real_cell(archive)
    readme, results_doc = _docs(tmp_path)
    argv = [str(results), "--readme", str(readme), "--results-doc", str(results_doc)]
    assert report_main(argv) == 0
    current, earlier = capsys.readouterr().out.split("\nEarlier recipe 2026-12-03 (")
    assert "| mira (ours) |  |" in current and "9% (100, 5-16)" in current
    assert "| mira (ours) | 77% (100, 68-84) / - † |" in earlier and "9% (100" not in earlier
    assert "77% (100, 68-84)" not in readme.read_text() + results_doc.read_text()
    page = results_doc.read_text()
    assert "Earlier recipe `2026-12-03`: 1 cells of this world, kept in " in page
    assert "`results/archive/recipe-2026-12-03/`" in page
    assert report_main([str(archive)]) == 0  # the archive folder itself
    assert "Earlier recipe 2026-12-03" in capsys.readouterr().out
    real_cell(archive, world="fedcba9876543210")  # another world's cell is no earlier recipe
    assert report_main([str(results)]) == 2
    assert "was measured in world fedcba9876543210" in capsys.readouterr().err


def test_the_table_holds_both_settings_both_measures_and_the_paper_under_its_labels(
    tmp_path, capsys
):
    results = tmp_path / "results"
    write_cell(results, "mira", "block-insertion", "normal", 81, 100, "nerf", strict=70)
    write_cell(results, "mira", "block-insertion", "challenging", 40, 100, "nerf", trained="normal")
    readme, results_doc = _docs(tmp_path)
    plot = tmp_path / "table1.png"
    argv = [str(results), "--readme", str(readme), "--results-doc", str(results_doc)]
    assert report_main(argv + ["--plot", str(plot)]) == 0
    header, _, mira, paper = capsys.readouterr().out.splitlines()[:4]
    assert header == (
        "| method | block-insertion | block-insertion Challenging | place-red-in-green | "
        "place-red-in-green Challenging | hanging-disks | hanging-disks Challenging | "
        "stacking-kits | stacking-kits Challenging |"
    )
    assert mira == (
        "| mira (ours) | 81% (100, 72-87) / 70% (100, 60-78) | 40% (100, 31-50) / - "
        "|  |  |  |  |  |  |"
    )
    # the paper's Challenging column stands under ours of its label: trained Normal
    assert paper == "| paper: its method | 80% |  | 86% | 50% | 40% |  | 32% |  |"
    assert "2 of 48 cells measured" in readme.read_text()
    text = results_doc.read_text()
    assert (
        "2 of 48 cells measured" in text and 'reads "under out-of-distribution rotations"' in text
    )
    assert (
        "    nerf-transporter run-cell --task block-insertion --test-setting challenging "
        "--method mira --steps 2000"
    ) in text
    # the bars of both of mira's cells, each in its task's Normal or Challenging group
    image = cv2.cvtColor(cv2.imread(str(plot)), cv2.COLOR_BGR2RGB)
    empty = table_plot([])
    assert image.shape == empty.shape
    mira_colour = empty[51, 67]
    drawn = (image[70:] == mira_colour).all(axis=2).any(axis=0).nonzero()[0]
    group = (image.shape[1] - 80) / 8
    assert sorted({int((x - 60) // group) for x in drawn}) == [0, 1]

    write_cell(results, "mira", "place-red-in-green", "challenging", 99, 100, "nerf")
    assert report_main([str(results)]) == 0
    header, _, mira, paper = capsys.readouterr().out.splitlines()[:4]
    assert header.endswith(
        "| stacking-kits Challenging | place-red-in-green Challenging (trained Challenging) |"
    )
    assert mira.endswith("|  | 99% (100, 95-100) / - |") and paper.endswith("| 32% |  |  |")


def test_a_cell_trained_and_tested_challenging_lies_in_its_own_column_folder(tmp_path, capsys):
    """Apart from the Challenging column of a Normal fit; an archived world's, written before,
    also where it lay then."""
    results = tmp_path / "results"
    archive = results / "archive" / f"world-{world_fingerprint()}"
    for root in (results, archive):
        write_cell(root, "form2fit", "place-red-in-green", "challenging", 30, 100)
    moved = archive / "place-red-in-green-challenging"
    (archive / "place-red-in-green-challenging-trained-challenging").rename(moved)
    assert report_main([str(results)]) == 0
    current, archived = capsys.readouterr().out.split("\nArchived world")
    for table in (current, archived):
        assert "| place-red-in-green Challenging (trained Challenging) |" in table
        assert table.splitlines()[-4].endswith("|  | 30% (100, 22-40) / - |")  # Form2Fit
    (results / "place-red-in-green-challenging-trained-challenging").rename(
        results / "place-red-in-green-challenging"
    )
    assert report_main([str(results)]) == 2
    assert (
        "holds the cell place-red-in-green-challenging-trained-challenging/form2fit.json"
        in capsys.readouterr().err
    )


def test_the_results_page_pairs_mira_with_each_row_on_their_common_seeds(tmp_path, capsys):
    """mira's seeds against each other row's, column by column (exact McNemar p); empty where a
    cell is missing or holds no episodes."""
    results = tmp_path / "results"
    write_cell(results, "mira", "block-insertion", "normal", 12, 20, "nerf", won=range(12))
    write_cell(results, "transporter_se2", "block-insertion", "normal", 2, 20, won={10, 11})
    write_cell(results, "form2fit", "block-insertion", "normal", 5, 20, won={0, 1, 2, 15, 16})
    write_cell(results, "transporter_se3", "block-insertion", "normal", 9, 20)  # no episodes
    write_cell(results, "form2fit", "hanging-disks", "normal", 4, 20, won=range(4))
    _, results_doc = _docs(tmp_path)
    assert report_main([str(results), "--results-doc", str(results_doc)]) == 0
    page = results_doc.read_text()
    table = page[page.index("| mira (ours) against |") :].split("\n\n")[0].splitlines()
    assert table[0].startswith("| mira (ours) against | block-insertion | block-insertion Chall")
    rows = {line.split(" | ")[0].removeprefix("| "): line.split(" | ")[1] for line in table[2:]}
    # 10 seeds mira only, none Transporter-SE(2) only: p = 2 / 2**10
    assert rows["Transporter-SE(2)"] == "10 / 0, p 0.002"
    # Form2Fit: 9 seeds mira only (3-11), 2 Form2Fit only (15, 16): p = 2 * 67 / 2**11
    assert rows["Form2Fit"] == "9 / 2, p 0.065"
    assert rows["Transporter-SE(3)"] == "" and rows["GT-State MLP"] == ""
    # hanging-disks: Form2Fit's cell has no mira cell to pair with
    assert table[[line.split(" | ")[0] for line in table].index("| Form2Fit")].endswith(
        "|  |  |  |  |  |  |"
    )


def test_report_names_a_row_or_column_that_mixes_recipes(tmp_path, capsys):
    """A row refitted on a new recipe beside a cell of the old one, one image row of a column
    with colour augmentation and another without, or one row of a column at another budget than
    the others: named on stderr, the table printed still. A budget the whole column shares is the
    column's, as the paper's budgets are its tasks'."""
    results = tmp_path / "results"
    for task in ("block-insertion", "place-red-in-green"):
        for row in ("mira", "transporter_se2", "gt_state_mlp"):
            write_cell(results, row, task, "normal", 50, 100)
    assert report_main([str(results)]) == 0
    assert "mixes recipes" not in capsys.readouterr().err

    def edit(path, **protocol):
        cell = json.loads(path.read_text())
        cell["protocol"] |= protocol
        path.write_text(json.dumps(cell))

    for row in ("mira", "transporter_se2", "gt_state_mlp"):
        edit(results / "place-red-in-green" / f"{row}.json", steps=9000)
    assert report_main([str(results)]) == 0
    assert "mixes recipes" not in capsys.readouterr().err
    edit(results / "place-red-in-green" / "gt_state_mlp.json", steps=2000)
    edit(results / "place-red-in-green" / "mira.json", view_choice="view_softmax")
    edit(results / "block-insertion" / "transporter_se2.json", colour_augment=True)
    edit(results / "block-insertion" / "gt_state_mlp.json", colour_augment=True)  # reads no image
    assert report_main([str(results)]) == 0
    out, err = capsys.readouterr()
    assert "| mira (ours) | 50% (100, 40-60) / - |" in out
    assert (
        'row mira (ours): view_choice: "-" in block-insertion; "view_softmax" in '
        "place-red-in-green\n"
    ) in err
    assert (
        "column block-insertion: colour_augment: false in mira (ours); true in Transporter-SE(2)"
    ) in err
    assert (
        "column place-red-in-green: steps: 2000 in GT-State MLP; 9000 in mira (ours), "
        "Transporter-SE(2)\n"
    ) in err
    # GT-State reads no image (its colour augmentation is no knob) and has one lr in its row:
    # the budget line is the only one that names it
    assert err.count("GT-State MLP") == 1 and "row Transporter-SE(2)" not in err


def test_a_nerf_cell_on_other_imagery_than_the_default_is_marked_not_a_mixed_recipe(
    tmp_path, capsys
):
    """A mira row re-measured on the default NeRF imagery one cell at a time: the cell still on
    the reference imagery is marked in the table, with the mark's legend in both results blocks,
    and the row is one recipe."""
    assert SceneSpec("hanging-disks").imagery_changes(), "the default is not the reference"
    results = tmp_path / "results"
    write_cell(
        results, "mira", "block-insertion", "normal", 50, 100, "nerf", reference_imagery=True
    )
    write_cell(results, "mira", "hanging-disks", "normal", 60, 100, "nerf")
    readme, results_doc = _docs(tmp_path)
    code = report_main([str(results), "--readme", str(readme), "--results-doc", str(results_doc)])
    assert code == 0
    out, err = capsys.readouterr()
    row = next(line for line in out.splitlines() if line.startswith("| mira (ours) |"))
    assert "| 50% (100, 40-60) / - † |" in row
    assert "| 60% (100, 50-69) / - |" in row
    assert "mixes recipes" not in err
    for page in (readme, results_doc):
        legend = "†: a NeRF-imagery cell measured on imagery other than this code's default"
        assert legend in page.read_text()
