"""Experiments: the runs of the methods and the results table built from them, above the
closed-loop evaluation (`nerf_transporter.evaluation`) that they measure with.

- `lightning_cli`: the LightningCLI of `lightning fit|validate|test|predict`;
- `runs`: run folders (`logs/<task>/<method>/version_N`): claimed, resumed, removed where unused;
- `run_cell`: `nerf-transporter run-cell`, one cell of the results table (fit, pick, test, write);
- `cache_imagery`: `nerf-transporter cache-imagery`, a split's evaluation imagery built ahead;
- `checkpoints`: `nerf-transporter evaluate-checkpoints`, validation success of every checkpoint;
- `cells`: the cell files of the results table and test records, read and checked (types, counts,
  world) for `report`, `compare-cells`, `failures` and `run-cell`;
- `report`: `nerf-transporter report`, the results table; `paper`: the paper's Table 1;
- `compare`: `nerf-transporter compare-cells`, cells paired on common seeds;
- `failures`: `nerf-transporter failures`, why the cells' test episodes failed;
- `pretrained`: the shipped policies, `nerf-transporter try` and `export-pretrained`.
"""
