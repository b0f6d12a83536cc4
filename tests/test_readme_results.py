"""The README's results section is the one `nerf-transporter report results/` writes."""

from pathlib import Path

from nerf_transporter.evaluation.cells import find_records
from nerf_transporter.evaluation.report import measured_cells, readme_block, replace_readme_block

REPO = Path(__file__).resolve().parents[1]
REGENERATE = (
    "run `nerf-transporter report results/ --readme README.md --plot results/table1.png` "
    "and commit README.md with results/"
)


def test_the_readme_results_section_matches_the_results_folder():
    found = find_records([REPO / "results"])
    records = found.records
    readme = (REPO / "README.md").read_text()
    expected = replace_readme_block(readme, readme_block(records, found.archives))
    assert readme == expected, f"README.md and results/ disagree: {REGENERATE}"
    if measured_cells(records):
        assert (REPO / "results" / "table1.png").is_file(), (
            f"results/table1.png is missing: {REGENERATE}"
        )
