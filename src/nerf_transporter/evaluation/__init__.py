"""Closed-loop evaluation (docs/conventions.md, "Evaluation protocol").

- `rollout`: one test episode for any method (`Evaluator`, `EvaluationSpec`, `EpisodeResult`);
- `workers`: the episodes of a round in worker processes, each with its own simulator and policy;
- `cache`: evaluation imagery cached on disk by task, setting, seed and imagery config;
- `metrics`: the `SuccessRate` torchmetrics metric, the 95% Wilson interval, a rate as the table
  writes it (`cell`);
- `callback`: `SuccessRateCallback`, validation success during training;
- `testing`: `evaluate_policy`, a policy on seeds -> its results record, and
  `ClosedLoopTestCallback` (the CLI adds it): `lightning test` plays the test seeds and writes
  `results-<checkpoint>.json` beside the checkpoint.

The experiments built on it (run-cell, the results table, ...) are `nerf_transporter.experiments`.
"""
