"""Closed-loop `trainer.test` (`lightning test --config ... --ckpt_path ...`).

The DataModule's test dataloader yields episode seeds (`seed_loader`; under DDP each process gets
its share); the methods' base class mixes in `ClosedLoopTest`, whose `test_step` collects them and
whose epoch end runs them with an `Evaluator` in the DataModule's `test_workers` worker processes
(default: one per core available to this process), pools the outcomes (across DDP processes), logs `test/success_rate`, its 95% Wilson interval, the
episode count and the erred episodes (`test/errors`, not counted in the rate), and writes
`results-<checkpoint>.json` beside the checkpoint (`results-<checkpoint>-<setting>.json` when the
DataModule's `test_setting` differs from its training `setting`). A results file is never
replaced: testing the same checkpoint again writes `...-2.json`, and `nerf-transporter report`
takes the newest. `lightning test` exits non-zero when any episode erred.
"""

from __future__ import annotations

import json
import os
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import DataLoader, Dataset

from nerf_transporter.atomic import write_new_json
from nerf_transporter.evaluation.metrics import summarize
from nerf_transporter.evaluation.rollout import EvaluationSpec, Evaluator
from nerf_transporter.parallel import share_cores
from nerf_transporter.sim.fingerprint import world_fingerprint
from nerf_transporter.splits import split_seed


def results_stem(
    checkpoint: str | None, global_step: int, setting: str, training_setting: str
) -> str:
    """`results-<checkpoint stem>` (`results-step<N>` without a checkpoint file), with
    `-<setting>` appended when testing in another setting than trained in."""
    name = Path(checkpoint).stem if checkpoint else f"step{global_step}"
    stem = f"results-{name}"
    return stem if setting == training_setting else f"{stem}-{setting}"


class SeedDataset(Dataset):
    """The first `episodes` seeds of a split (`splits.split_seed`)."""

    def __init__(self, split: str, episodes: int) -> None:
        if episodes < 1:
            raise ValueError(f"episodes must be >= 1, got {episodes}")
        split_seed(split, episodes - 1)  # validates the split name and the range
        self.split = split
        self.episodes = episodes

    def __len__(self) -> int:
        return self.episodes

    def __getitem__(self, index: int) -> int:
        return split_seed(self.split, index)


def seed_loader(split: str, episodes: int) -> DataLoader:
    """One seed per batch, in order (the test progress bar then counts episodes)."""
    return DataLoader(SeedDataset(split, episodes), batch_size=1, shuffle=False)


def results_record(
    results: list[dict[str, Any]],
    *,
    method: torch.nn.Module,
    spec: EvaluationSpec,
    split: str,
    checkpoint: str | None,
    global_step: int | None,
    wall_s: float,
) -> dict[str, Any]:
    """The results file's payload: identification, summary figures and every episode's record.

    "imagery" is how the views were built for an imagery method (nerf, oracle), None for the
    methods that see the RGB-D heightmap or the state.
    """
    results = sorted(results, key=lambda result: result["seed"])
    return {
        "method": method_name(method),
        "task": spec.task,
        "setting": spec.setting,
        "split": split,
        "imagery": spec.imagery if getattr(method, "input_kind", None) == "imagery" else None,
        "checkpoint": checkpoint,
        "global_step": global_step,
        "world": world_fingerprint(),
        **summarize(results),
        "wall_s": wall_s,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "episode_results": results,
    }


def checkpoint_step(path: str | os.PathLike) -> int:
    """The global step a checkpoint was saved at."""
    checkpoint = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    return int(checkpoint["global_step"])


def method_name(module: torch.nn.Module) -> str:
    """The name of a method (`mira`, `transporter_se2`, ...: the class attribute `name`)."""
    return str(getattr(module, "name", type(module).__name__))


def erred_episodes_text(record: dict[str, Any]) -> str:
    """One line per erred episode of a results record, under a headline."""
    erred = [result for result in record["episode_results"] if result.get("error") is not None]
    lines = [f"  seed {result['seed']}: {result['error']}" for result in erred]
    return (
        f"{len(erred)} of {len(record['episode_results'])} episodes erred (not the robot's doing; "
        "left out of the success rate):\n" + "\n".join(lines)
    )


def erred_seeds_line(record: dict[str, Any]) -> str:
    """The erred episodes of a results record in one line, with what to do."""
    seeds = ", ".join(str(seed) for seed in record["erred_seeds"])
    return (
        f"{record['errors']} episodes erred (seeds {seeds}) and are left out of the success rate; "
        "fix the cause (see the messages above) and test again"
    )


class ClosedLoopTest:
    """Mixin for the methods' LightningModule base class: `trainer.test` runs closed-loop episodes.

    With `test_video_dir` set (`lightning test ... --video DIR`), every episode is also recorded
    there as an mp4. After a test, `test_record` holds the results payload (for the CLI's exit
    status)."""

    test_record: dict[str, Any] | None = None
    test_video_dir: str | None = None

    def on_test_epoch_start(self) -> None:
        self._test_seeds: list[int] = []
        self._test_start = time.perf_counter()

    def test_step(self, batch: torch.Tensor, batch_idx: int) -> None:
        """Collect this process's seeds; they run together at the end of the epoch, so that the
        worker processes share them out as they become free."""
        self._test_seeds.extend(int(seed) for seed in torch.as_tensor(batch).flatten().tolist())

    def on_test_epoch_end(self) -> None:
        datamodule = self.trainer.datamodule
        spec = EvaluationSpec.from_datamodule(datamodule, split="test")
        seeds, start = self._test_seeds, self._test_start
        workers, threads = share_cores(
            len(seeds), getattr(datamodule, "test_workers", None), self.trainer.num_devices
        )
        with Evaluator(spec) as evaluator:
            episodes = evaluator.run(
                self,
                seeds,
                progress=self.trainer.is_global_zero,
                desc="test episodes",
                workers=workers,
                threads=threads,
                video_dir=self.test_video_dir,
            )
        results = [episode.to_json() for episode in episodes]
        if self.trainer.world_size > 1:
            results = gather_json(self, results)
        checkpoint = self.trainer.ckpt_path
        if not checkpoint:
            step = self.global_step
        elif Path(checkpoint).is_file():
            step = checkpoint_step(checkpoint)
        else:
            step = None  # a checkpoint behind a URL: Lightning read it, its step is not at hand
        record = results_record(
            results,
            method=self,
            spec=spec,
            split="test",
            checkpoint=str(checkpoint) if checkpoint else None,
            global_step=step,
            wall_s=time.perf_counter() - start,
        )
        for name in ("success_rate", "ci_low", "ci_high", "episodes", "errors"):
            if record[name] is not None:  # rounded for Lightning's table; the file keeps all digits
                self.log(f"test/{name}", round(float(record[name]), 4))
        self.test_record = record
        # trainer.log_dir is a collective call under DDP: every process asks for it
        directory = Path(checkpoint).parent if checkpoint else Path(self.trainer.log_dir or ".")
        if self.trainer.is_global_zero:
            stem = results_stem(
                record["checkpoint"],
                record["global_step"],
                record["setting"],
                self.trainer.datamodule.setting,
            )
            path = write_new_json(directory, stem, record)
            print(f"closed-loop test results written to {path}")
            if record["errors"]:
                print(erred_episodes_text(record), file=sys.stderr)


def gather_json(module: Any, records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Concatenate every process's JSON records (sent as padded byte tensors: no pickle)."""
    payload = torch.tensor(list(json.dumps(records).encode()), dtype=torch.uint8)
    sizes = module.all_gather(torch.tensor(len(payload), device=module.device)).flatten()
    padded = torch.zeros(int(sizes.max()), dtype=torch.uint8)
    padded[: len(payload)] = payload
    parts = module.all_gather(padded.to(module.device)).cpu()
    return [
        record
        for part, size in zip(parts, sizes.tolist(), strict=True)
        for record in json.loads(bytes(part[:size].tolist()).decode())
    ]
