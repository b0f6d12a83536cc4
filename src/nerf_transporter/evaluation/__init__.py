"""Closed-loop evaluation (docs/conventions.md, "Evaluation protocol").

- `rollout`: one test episode for any method (`Evaluator`, `EvaluationSpec`, `EpisodeResult`);
- `workers`: the episodes of a round in worker processes, each with its own simulator and policy;
- `cache`: evaluation imagery cached on disk by task, setting, seed and imagery config;
- `metrics`: the `SuccessRate` torchmetrics metric and the 95% Wilson interval;
- `callback`: `SuccessRateCallback`, validation success during training;
- `testing`: `ClosedLoopTestCallback` (the CLI adds it): `lightning test` plays the test seeds
  and writes `results-<checkpoint>.json` beside the checkpoint;
- `checkpoints`: `nerf-transporter evaluate-checkpoints`, validation success of every checkpoint;
- `cells`: the cell files of the results table and test records, read and checked (types, counts,
  world) for `report`, `compare-cells`, `failures` and `run-cell`;
- `report`: `nerf-transporter report`, the results table.
"""
