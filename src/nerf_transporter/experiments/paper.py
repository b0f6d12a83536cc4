"""The paper's Table 1, the values our results table is set against (the one place they live).

Quoted as given from the write-up this project started from, "NeRF-based Action Evaluation for
Robotic Grasping" (a restatement of MIRA, Lin et al., CoRL 2022; README, "Citation"), Table 1:
"Quantitative results (trained on 10 generated senarios). Task success rate (%) under
out-of-distribution rotations for four tasks. All models are trained on 10 expert demonstrations."
The write-up does not state its number of test episodes. Its "Ours" row is the method `mira`
reimplements; it has no row with oracle imagery.
"""

from __future__ import annotations

# (task, setting) columns of Table 1, in its order
PAPER_COLUMNS: tuple[tuple[str, str], ...] = (
    ("block-insertion", "normal"),
    ("place-red-in-green", "normal"),
    ("hanging-disks", "normal"),
    ("stacking-kits", "normal"),
    ("place-red-in-green", "challenging"),
)
# training iterations at batch 1, per column (the table's second header line)
PAPER_ITERATIONS: dict[tuple[str, str], int] = dict(
    zip(PAPER_COLUMNS, (40000, 24000, 9000, 20000, 40000), strict=True)
)
# success % per method (our names) and column
PAPER_SUCCESS: dict[str, dict[tuple[str, str], int]] = {
    method: dict(zip(PAPER_COLUMNS, values, strict=True))
    for method, values in {
        "mira": (80, 86, 40, 32, 50),  # the write-up's "Ours"
        "transporter_se2": (21, 74, 32, 18, 18),
        "transporter_se3": (20, 77, 32, 16, 20),
        "form2fit": (0, 79, 1, 4, 30),
        "gt_state_mlp": (0, 1, 0, 0, 1),
    }.items()
}
