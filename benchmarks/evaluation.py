"""Wall time of one validation round, serial vs in worker processes (`Evaluator.run(workers=N)`).

    python benchmarks/evaluation.py [--method state|mira] [--episodes 8] [--workers 2] [--json]

Each mode gets a fresh Evaluator and runs the round twice: the first ("cold") builds the simulators
(and, with workers, starts the processes), the second ("warm") reuses them, as the validation rounds
of a training run do. The state policy moves the object from its pose in the state to the target's
(a trained gt_state_mlp's actions, without its errors), so every episode runs the whole
pick-and-place motion; mira has random weights and sees oracle imagery at the quick configs' pixel
size, 6.25 mm, with their network size.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np
import torch

from nerf_transporter.evaluation.rollout import EvaluationSpec, Evaluator
from nerf_transporter.methods import Mira
from nerf_transporter.parallel import available_cores
from nerf_transporter.splits import split_seed


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


class StatePolicy(torch.nn.Module):
    """Picks the object at its pose in the state and places it at the target pose in the state
    (block-insertion's state: object xyz, quaternion, then target xyz, quaternion)."""

    input_kind = "state"

    def worker_factory(self) -> type[StatePolicy]:
        return StatePolicy

    def act(self, observation: dict) -> dict:
        state = np.asarray(observation["state"], dtype=float)
        return {"pick": (state[:3], state[3:7]), "place": (state[7:10], state[10:14])}


def build(method: str, task: str) -> tuple[torch.nn.Module, EvaluationSpec]:
    torch.manual_seed(0)
    if method == "state":
        return StatePolicy(), EvaluationSpec(task=task, imagery="oracle", cache_dir=None)
    pixel_size = 0.00625
    model = Mira(pixel_size=pixel_size, n_rotations=36, crop_size=32, width=8)
    return model, EvaluationSpec(task=task, imagery="oracle", pixel_size=pixel_size, cache_dir=None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", choices=("state", "mira"), default="state")
    parser.add_argument("--task", default="block-insertion")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    model, spec = build(args.method, args.task)
    seeds = [split_seed("validation", index) for index in range(args.episodes)]
    cores = available_cores()
    figures: dict = {
        "method": args.method,
        "task": args.task,
        "episodes": args.episodes,
        "pixel_size": spec.pixel_size,
        "cpu": cpu_model(),
        "cores": cores,
        "serial_torch_threads": torch.get_num_threads(),
        "workers": args.workers,
        "worker_torch_threads": max(1, cores // args.workers),
    }
    outcomes = {}
    for workers in (1, args.workers):
        mode = "serial" if workers == 1 else f"{workers}_workers"
        with Evaluator(spec) as evaluator:
            for round_name in ("cold", "warm"):
                start = time.perf_counter()
                results = evaluator.run(model, seeds, workers=workers)
                figures[f"{mode}_{round_name}_s"] = time.perf_counter() - start
        outcomes[mode] = [result.outcome for result in results]
    figures["same_outcomes"] = len(set(map(tuple, outcomes.values()))) == 1
    for round_name in ("cold", "warm"):
        serial = figures[f"serial_{round_name}_s"]
        figures[f"speedup_{round_name}"] = (
            serial / figures[f"{args.workers}_workers_{round_name}_s"]
        )
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key:>24}: {value:.2f}" if isinstance(value, float) else f"{key:>24}: {value}")


if __name__ == "__main__":
    main()
