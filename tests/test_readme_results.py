"""The README's results section is the one `nerf-transporter report results/` writes."""

from pathlib import Path

from nerf_transporter.evaluation.report import (
    load_results,
    measured_cells,
    readme_block,
    replace_readme_block,
)

REPO = Path(__file__).resolve().parents[1]
REGENERATE = (
    "run `nerf-transporter report results/ --readme README.md --plot results/table1.png` "
    "and commit README.md with results/"
)


def test_the_readme_results_section_matches_the_results_folder():
    records = load_results([REPO / "results"])
    readme = (REPO / "README.md").read_text()
    expected = replace_readme_block(readme, readme_block(records))
    assert readme == expected, f"README.md and results/ disagree: {REGENERATE}"
    if measured_cells(records):
        assert (REPO / "results" / "table1.png").is_file(), (
            f"results/table1.png is missing: {REGENERATE}"
        )
