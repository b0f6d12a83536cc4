"""Simulator speed: reset, oracle episode, capture per rig, one orthographic view (medians).

    python benchmarks/sim.py [--task block-insertion] [--setting normal] [--repeats 5] [--json]

Targets on a 2-core CPU: oracle episode (reset + pick-and-place) <= 3 s, 30-view NeRF capture
<= 4 s, one orthographic view <= 30 ms.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

from nerf_transporter.sim import make_env


def _median_seconds(function, repeats: int) -> float:
    times = []
    for k in range(repeats):
        start = time.perf_counter()
        function(k)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="block-insertion")
    parser.add_argument("--setting", default="normal")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--nerf-views", type=int, default=30)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    env = make_env(args.task, args.setting)
    seed = 100001

    def episode(k: int) -> None:
        env.reset(seed=seed + k)
        env.step(env.task.oracle(env))

    figures = {
        "task": args.task,
        "setting": args.setting,
        "repeats": args.repeats,
        "machine": f"{platform.machine()} {os.cpu_count()} cpus",
        "reset_s": _median_seconds(lambda k: env.reset(seed=seed + k), args.repeats),
        "oracle_episode_s": _median_seconds(episode, args.repeats),
    }
    env.close()
    rigs = make_env(args.task, args.setting, rigs=("rgbd", "nerf"), nerf_views=args.nerf_views)
    rigs.reset(seed=seed)
    figures["capture_rgbd_s"] = _median_seconds(lambda _: rigs.capture("rgbd"), args.repeats)
    figures[f"capture_nerf_{args.nerf_views}_views_s"] = _median_seconds(
        lambda _: rigs.capture("nerf"), args.repeats
    )
    figures["orthographic_view_s"] = _median_seconds(
        lambda k: rigs.render_orthographic(0.1 * (k % 3), -0.1), max(args.repeats, 10)
    )
    rigs.close()
    if args.json:
        print(json.dumps(figures))
    else:
        for key, value in figures.items():
            print(f"{key:>28}: {value:.4f}" if isinstance(value, float) else f"{key:>28}: {value}")


if __name__ == "__main__":
    main()
