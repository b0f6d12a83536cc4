"""Time of one training step per method at full size, and of `mira.act` over the 49-view grid.

Full size: 320 x 160 images (pixel size 0.003125 m), 36 rotations, 64 x 64 crops, batch size 1,
`mira` with one negative view; the width is the configs' (`--width` to change it). Inputs are random
tensors of the documented batch layout (the step time does not depend on the content).

    python benchmarks/train_step.py [--json] [--width 16] [--repeats 3] [--device cpu] [--threads 1]
                                    [--precision bf16-mixed] [--cuda-graphs] [--profile]

`--cuda-graphs` runs the networks' training passes as CUDA graphs, as `model.init_args.cuda_graphs`
(configs/gpu/cuda_graphs.yaml) does in a fit; the optimiser is the methods' own (fused Adam on CUDA).

Each step's floating-point operations (forward + backward, counted once by
`torch.utils.flop_counter`: convolutions and matrix products, not the FFTs) are reported beside its
time, with the rate achieved: where that rate is near the processor's peak, only fewer operations
make the step faster.

On a CPU shared with other processes, two OpenMP threads can be ~10x slower than one (measured:
mira step 21 s with 2 threads vs 2.5 s with 1 at load average 3); compare figures at equal load.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import numpy as np
import torch
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile
from torch.utils.flop_counter import FlopCounterMode

from nerf_transporter import geometry as g
from nerf_transporter.device_info import describe_device, device_line
from nerf_transporter.methods import METHODS, Method
from nerf_transporter.models.graphs import graph_training_passes, to_channels_last

STATE_DIM = 28


def full_size_batch(input_kind: str, n_negative_views: int, device: torch.device) -> dict:
    """One sample (B = 1) in the layout of docs/interfaces.md."""
    height, width = g.image_shape()
    pixel = torch.tensor([[height // 2, width // 2]], device=device)
    labels = {"pick_pixel": pixel, "place_pixel": pixel + 10, "rotation_bin": torch.tensor([3])}
    if input_kind == "state":
        pose = torch.tensor([[0.5, 0.0, 0.05, 0.0, 0.0, 0.0, 1.0]])
        return {"state": torch.randn(1, STATE_DIM), "pick": pose, "place": pose}
    if input_kind == "imagery":
        return {
            **labels,
            "pick_image": torch.randn(1, 6, height, width),
            "place_images": torch.randn(1, 1 + n_negative_views, 6, height, width),
        }
    return {
        **labels,
        "image": torch.randn(1, 6, height, width),
        "place_z": torch.tensor([0.05]),
        "place_roll": torch.tensor([0.1]),
        "place_pitch": torch.tensor([-0.1]),
    }


def synchronise(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def autocast(device: torch.device, precision: str) -> torch.autocast:
    """The forward pass's precision as Lightning's `trainer.precision` sets it."""
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bf16-mixed")


def train_step(
    method: Method,
    optimiser: torch.optim.Optimizer,
    batch: dict,
    device: torch.device,
    precision: str,
) -> None:
    """Forward + backward + Adam step, as Lightning runs it at `precision`."""
    with autocast(device, precision):
        loss = method.losses(batch)["loss"]
    optimiser.zero_grad()
    loss.backward()
    optimiser.step()


def time_steps(
    method: Method, batch: dict, repeats: int, device: torch.device, precision: str
) -> float:
    """Median seconds of a training step (after one warm-up step)."""
    batch = {key: value.to(device) for key, value in batch.items()}
    optimiser = method.configure_optimizers()
    times = []
    for _ in range(repeats + 1):
        synchronise(device)
        start = time.perf_counter()
        train_step(method, optimiser, batch, device, precision)
        synchronise(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times[1:])


def profile_steps(
    method: Method, batch: dict, device: torch.device, precision: str, steps: int = 3
) -> dict:
    """Per training step: GPU kernels launched, GPU busy time and wall time under `torch.profiler`
    (which adds host overhead of its own), which tell a step waiting on launches (busy << step)
    from one waiting on arithmetic."""
    batch = {key: value.to(device) for key, value in batch.items()}
    optimiser = method.configure_optimizers()
    train_step(method, optimiser, batch, device, precision)
    synchronise(device)
    activities = [ProfilerActivity.CPU]
    if device.type == "cuda":
        activities.append(ProfilerActivity.CUDA)
    start = time.perf_counter()
    with profile(activities=activities) as profiler:
        for _ in range(steps):
            train_step(method, optimiser, batch, device, precision)
        synchronise(device)
    wall = time.perf_counter() - start
    kernels = [e for e in profiler.events() if e.device_type == DeviceType.CUDA]

    def busy_us(event) -> float:  # GPU time on a GPU, else the host's own time
        return event.device_time_total if device.type == "cuda" else event.self_cpu_time_total

    busiest = sorted(profiler.key_averages(), key=busy_us, reverse=True)
    return {
        "kernels": round(len(kernels) / steps),
        "gpu_busy_ms": round(sum(e.device_time for e in kernels) / steps / 1000, 2),
        "profiled_step_ms": round(wall / steps * 1000, 2),
        "busiest_ops_ms": {e.key[:60]: round(busy_us(e) / steps / 1000, 2) for e in busiest[:12]},
    }


def step_gflop(method: Method, batch: dict, device: torch.device, precision: str) -> float:
    """Floating-point operations of one forward + backward pass, in GFLOP."""
    batch = {key: value.to(device) for key, value in batch.items()}
    with FlopCounterMode(display=False) as counter:
        with autocast(device, precision):
            loss = method.losses(batch)["loss"]
        loss.backward()
    method.zero_grad(set_to_none=True)
    return counter.get_total_flops() / 1e9


def time_mira_act(method: Method, repeats: int, device: torch.device) -> float:
    views = g.view_grid("normal")
    rng = np.random.default_rng(0)
    shape = (len(views), *g.image_shape())
    observation = {
        "imagery": {
            "colour": rng.integers(0, 256, (*shape, 3), dtype=np.uint8),
            "height": rng.uniform(0, 0.1, shape).astype(np.float16),
            "views": views,
        }
    }
    times = []
    for _ in range(repeats):
        synchronise(device)
        start = time.perf_counter()
        method.act(observation)
        synchronise(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=None, help="FCN width (default: configs')")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--negative-views", type=int, default=1)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument(
        "--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)"
    )
    parser.add_argument(
        "--precision",
        default="32-true",
        choices=["32-true", "bf16-mixed"],
        help="training precision, as trainer.precision (configs/gpu/bf16.yaml: bf16-mixed)",
    )
    parser.add_argument(
        "--cuda-graphs",
        action="store_true",
        help="run the networks' training passes as CUDA graphs (model.init_args.cuda_graphs)",
    )
    parser.add_argument(
        "--profile",
        action="store_true",
        help="also profile 3 steps: GPU kernels, GPU busy time and host time per step",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    torch.manual_seed(0)
    results: dict = {
        "device": describe_device(device),
        "load_average_before": os.getloadavg()[0],
        "image_shape": list(g.image_shape()),
        "n_rotations": 36,
        "crop_size": 64,
        "negative_views": args.negative_views,
        "precision": args.precision,
        "cuda_graphs": args.cuda_graphs,
        "step_seconds": {},
        "step_gflop": {},
    }
    for name in args.methods:
        cls = METHODS[name]
        kwargs = {"state_dim": STATE_DIM} if cls.input_kind == "state" else {}
        if args.width is not None and cls.input_kind != "state":
            kwargs["width"] = args.width
        method = cls(**kwargs).to(device)
        if cls.input_kind != "state":
            results["width"] = method.hparams["width"]
        batch = full_size_batch(cls.input_kind, args.negative_views, device)
        results["step_gflop"][name] = round(step_gflop(method, batch, device, args.precision), 3)
        if args.cuda_graphs and cls.input_kind != "state":
            for net in method.networks():  # captured in the warm-up step, outside the counter
                to_channels_last(net)
                graph_training_passes(net)
        results["step_seconds"][name] = round(
            time_steps(method, batch, args.repeats, device, args.precision), 4
        )
        if args.profile:
            results.setdefault("profile", {})[name] = profile_steps(
                method, batch, device, args.precision
            )
        if name == "mira":
            results["mira_act_49_views_seconds"] = round(
                time_mira_act(method, args.repeats, device), 4
            )
        if not args.json:
            seconds, gflop = results["step_seconds"][name], results["step_gflop"][name]
            print(
                f"{name:<16} step {seconds:.3f} s  {gflop:.3g} GFLOP  {gflop / seconds:.3g} GFLOP/s",
                flush=True,
            )
            if args.profile:
                found = results["profile"][name]
                print(
                    f"{'':<16} profiled: {found['kernels']} GPU kernels, GPU busy "
                    f"{found['gpu_busy_ms']} ms of a {found['profiled_step_ms']} ms step; "
                    "busiest: "
                    + ", ".join(f"{op} {ms} ms" for op, ms in found["busiest_ops_ms"].items()),
                    flush=True,
                )
    results["load_average_after"] = os.getloadavg()[0]
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print(f"mira.act over 49 views: {results.get('mira_act_49_views_seconds', 'n/a')} s")
        print(
            f"{device_line(results['device'])}, load average "
            f"{results['load_average_before']:.1f} -> {results['load_average_after']:.1f}"
        )


if __name__ == "__main__":
    main()
