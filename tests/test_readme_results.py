"""The README's results section and docs/results.md are what `nerf-transporter report results/`
writes."""

from pathlib import Path

from nerf_transporter.experiments.cells import find_records
from nerf_transporter.experiments.report import (
    README_END,
    README_START,
    RESULTS_DOC_END,
    RESULTS_DOC_START,
    markdown,
    measured_cells,
    mixed_recipes,
    readme_block,
    replace_block,
    results_doc_block,
    results_table,
)

REPO = Path(__file__).resolve().parents[1]
REGENERATE = (
    "run `nerf-transporter report results/ --readme README.md --results-doc docs/results.md "
    "--plot results/table1.png` and commit README.md and docs/results.md with results/"
)


def test_the_readme_results_section_matches_the_results_folder():
    found = find_records([REPO / "results"])
    records = found.records
    readme = (REPO / "README.md").read_text()
    expected = replace_block(readme, readme_block(records), README_START, README_END)
    assert readme == expected, f"README.md and results/ disagree: {REGENERATE}"
    if measured_cells(records):
        assert (REPO / "results" / "table1.png").is_file(), (
            f"results/table1.png is missing: {REGENERATE}"
        )


def test_the_results_page_matches_the_results_folder():
    found = find_records([REPO / "results"])
    page = (REPO / "docs" / "results.md").read_text()
    block = results_doc_block(found.records, found.archives)
    expected = replace_block(page, block, RESULTS_DOC_START, RESULTS_DOC_END)
    assert page == expected, f"docs/results.md and results/ disagree: {REGENERATE}"


def test_the_archived_worlds_page_holds_the_table_report_renders_for_it():
    found = find_records([REPO / "results"])
    page = (REPO / "docs" / "archive" / "results.md").read_text()
    worlds = [archive for archive in found.archives if archive.recipe is None]
    assert worlds, "results/archive/ holds no earlier world: docs/archive/ describes one"
    for archive in worlds:  # an earlier recipe's cells are this world's: `report` prints them
        table = markdown(*results_table(archive.cells))
        assert f"`{archive.world}`" in page and table in page, (
            f"docs/archive/results.md lacks the table of world {archive.world}: paste it from "
            "`nerf-transporter report results/`"
        )


def test_the_committed_table_and_each_earlier_recipe_are_one_recipe_a_row():
    found = find_records([REPO / "results"])
    assert mixed_recipes(found.records) == [], "a refitted row's earlier cells go to the archive"
    for archive in found.archives:
        if archive.recipe is not None:
            assert mixed_recipes(archive.cells) == [], archive.folder
