"""Closed-loop evaluation (docs/conventions.md, "Evaluation protocol").

- `rollout`: one test episode for any method (`Evaluator`, `EvaluationSpec`, `EpisodeResult`);
- `workers`: the episodes of a round in worker processes, each with its own simulator and policy;
- `cache`: evaluation imagery cached on disk by task, setting, seed and imagery config;
- `metrics`: the `SuccessRate` torchmetrics metric and the 95% Wilson interval;
- `callback`: `SuccessRateCallback`, validation success during training;
- `testing`: `ClosedLoopTestCallback` (the CLI adds it): `lightning test` plays the test seeds
  and writes `results-<checkpoint>.json` beside the checkpoint.

The experiments built on it (run-cell, the results table, ...) are `nerf_transporter.experiments`.
"""
