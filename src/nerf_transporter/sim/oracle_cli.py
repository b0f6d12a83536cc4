"""`nerf-transporter oracle`: run oracle episodes of a task and report the success rate."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
from tqdm import tqdm

from nerf_transporter.console import HelpFormatter, progress_bar
from nerf_transporter.sim.env import make_env
from nerf_transporter.sim.tasks import SETTINGS, TASKS

VIDEO_SUFFIXES = (".mp4", ".gif")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter oracle",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--task", required=True, choices=sorted(TASKS), help="task family")
    parser.add_argument(
        "--setting", default="normal", choices=SETTINGS, help="tilt range of the targets"
    )
    parser.add_argument("--episodes", type=int, default=10, help="episodes to run")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (then +1)")
    parser.add_argument("--json", action="store_true", help="end with one JSON summary line")
    parser.add_argument(
        "--video", type=Path, help="record the first episode from a fixed camera (.mp4 or .gif)"
    )
    return parser


def _write_video(path: Path, frames: list[np.ndarray], fps: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
    if path.suffix == ".gif":
        imageio.mimsave(tmp, frames, duration=1000 / fps, loop=0)
    else:
        imageio.mimsave(tmp, frames, fps=fps, macro_block_size=8)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.episodes < 1:
        print("oracle: --episodes must be at least 1", file=sys.stderr)
        return 2
    if args.seed < 0:
        print(f"oracle: --seed must be >= 0 (a scene's seed), got {args.seed}", file=sys.stderr)
        return 2
    if args.video is not None and args.video.suffix not in VIDEO_SUFFIXES:
        print(f"oracle: --video must end with {' or '.join(VIDEO_SUFFIXES)}", file=sys.stderr)
        return 2
    try:
        env = make_env(args.task, args.setting, render_mode="rgb_array" if args.video else None)
    except ValueError as error:
        print(f"oracle: {error}", file=sys.stderr)
        return 2
    frames: list[np.ndarray] = []
    successes = strict_successes = 0
    with progress_bar(args.episodes, f"{args.task}-{args.setting}") as progress:
        for index in range(args.episodes):
            seed = args.seed + index
            env.reset(seed=seed)
            recording = args.video is not None and index == 0
            if recording:
                env.frame_callback = frames.append
                frames.append(env.render())
            _, reward, _, _, info = env.step(env.task.oracle(env))
            env.frame_callback = None
            successes += int(info["success"])
            strict_successes += int(info["strict_success"])
            progress.set_postfix(success_rate=f"{successes / (index + 1):.2f}")
            tqdm.write(
                f"episode {index} seed {seed}: success={info['success']} reward={reward:.0f} "
                f"strict_success={info['strict_success']} "
                f"position_error_mm={1000 * info.get('position_error', float('nan')):.1f} "
                f"failure={info['failure']}",
                file=sys.stdout,
            )
            progress.update(1)
    env.close()
    if args.video is not None:
        _write_video(args.video, frames, env.metadata["render_fps"])
        print(f"video: {args.video} ({len(frames)} frames)", file=sys.stderr)
    summary = {
        "task": args.task,
        "setting": args.setting,
        "episodes": args.episodes,
        "successes": successes,
        "success_rate": successes / args.episodes,
        "strict_successes": strict_successes,
        "strict_success_rate": strict_successes / args.episodes,
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"{args.task} {args.setting}: {successes}/{args.episodes} successful "
            f"({strict_successes}/{args.episodes} by the strict 6-DoF check)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
