"""Which half of the NeRF imagery a policy cannot read: a checkpoint tested on views whose colour
comes from one imagery (nerf or oracle) and whose height from the other.

    python benchmarks/imagery_swap.py logs/cells/<column>/<row>/<id>/version_0 \
        --checkpoint step002000-success0.35.ckpt --setting challenging \
        --colour nerf --height oracle --episodes 100 \
        --record results/sweep/imagery-swap/<name>.json

Both imageries of the first --episodes test seeds must already be in the imagery cache
(`--cache-dir`, where `evaluate-checkpoints --imagery nerf|oracle` leaves them): nothing is fitted
here. `--imagery-option KEY=VALUE` takes the NeRF half from an imagery candidate instead of the
training data's imagery (as `evaluate-checkpoints --imagery-option`, which caches it). The composed views are written to a cache of their own (`--swap-cache`) under the key of the
NeRF imagery, and the checkpoint is tested there by `evaluate-checkpoints`' own code, so the
episodes are the protocol's but for the views. The record is the test record it writes (also kept
in the run's `evaluation/`), with `imagery_swap` ({"colour": ..., "height": ...}) added; pair it with
`compare-cells`, break it down with `failures`.

`--colour-blur SIGMA` blurs the colour half with a Gaussian of SIGMA pixels, the same in every view:
with `--colour oracle --height oracle` it measures what a blur alone costs the policy, the swap
test's control for the NeRF's soft edges (docs/imagery.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from nerf_transporter.atomic import write_json
from nerf_transporter.console import progress_bar
from nerf_transporter.data.generate import add_imagery_option_argument
from nerf_transporter.data.observation import IMAGERY_KINDS
from nerf_transporter.evaluation.cache import ImageryCache
from nerf_transporter.evaluation.rollout import DEFAULT_CACHE_DIR, EvaluationSpec
from nerf_transporter.experiments.checkpoints import (
    chosen_checkpoints,
    evaluate_checkpoints,
    imagery_options_suffix,
    load_checkpoint,
)
from nerf_transporter.splits import split_seed


def swapped_views(colour_from: dict, height_from: dict) -> dict[str, np.ndarray]:
    """The views of `colour_from` with the heights of `height_from` (same grid, else ValueError)."""
    if not np.array_equal(colour_from["views"], height_from["views"]):
        raise ValueError("the two imageries are of different view grids")
    if colour_from["height"].shape != height_from["height"].shape:
        raise ValueError(
            f"the two imageries' images differ in size: {colour_from['height'].shape} and "
            f"{height_from['height'].shape}"
        )
    return {
        "colour": colour_from["colour"],
        "height": height_from["height"],
        "views": colour_from["views"],
    }


def blurred(colour: np.ndarray, sigma: float) -> np.ndarray:
    """Views' colour [V, H, W, 3] uint8, each blurred by a Gaussian of `sigma` pixels (borders
    reflected); `sigma` 0 returns them as they are."""
    if sigma < 0:
        raise ValueError(f"a blur's sigma is at least 0 pixels, got {sigma}")
    if sigma == 0:
        return colour
    return np.stack([cv2.GaussianBlur(view, (0, 0), sigma) for view in colour])


def build_swap_cache(
    specs: dict[str, EvaluationSpec],
    colour: str,
    height: str,
    seeds: list[int],
    source: ImageryCache,
    target: ImageryCache,
    colour_blur: float = 0.0,
) -> None:
    """Write each seed's swapped views (the colour blurred by `colour_blur` pixels) into `target`
    under the key of `specs["nerf"]`."""
    nerf = specs["nerf"]
    with progress_bar(len(seeds), f"compose {colour} colour + {height} height") as bar:
        for seed in seeds:
            parts = {}
            for kind in (colour, height):
                parts[kind] = source.load(nerf.task, nerf.setting, seed, specs[kind].imagery_key())
                if parts[kind] is None:
                    raise FileNotFoundError(
                        f"no {kind} imagery of {nerf.task} {nerf.setting} seed {seed} in "
                        f"{source.root}: run `nerf-transporter evaluate-checkpoints <run> "
                        f"--split test --imagery {kind} --setting {nerf.setting}` first"
                    )
            views = swapped_views(parts[colour], parts[height])
            views["colour"] = blurred(views["colour"], colour_blur)
            target.save(nerf.task, nerf.setting, seed, nerf.imagery_key(), views)
            bar.update()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, help="the run folder of the checkpoint")
    parser.add_argument("--checkpoint", type=Path, required=True, help="its file name or path")
    parser.add_argument("--setting", default=None, help="test setting (default: the training one)")
    parser.add_argument("--colour", choices=IMAGERY_KINDS, required=True)
    parser.add_argument("--height", choices=IMAGERY_KINDS, required=True)
    parser.add_argument(
        "--colour-blur",
        type=float,
        default=0.0,
        metavar="SIGMA",
        help="blur the colour half by a Gaussian of SIGMA pixels (with --colour oracle --height "
        "oracle: what a blur alone costs)",
    )
    parser.add_argument("--episodes", type=int, default=100, help="the first test seeds")
    parser.add_argument("--cache-dir", default=DEFAULT_CACHE_DIR, help="the cache read from")
    parser.add_argument(
        "--swap-cache",
        type=Path,
        default=Path("data/imagery-swap"),
        help="the cache of the swapped views (<swap-cache>/<colour>-colour-<height>-height/)",
    )
    parser.add_argument("--eval-workers", type=int, default=1, help="episode processes")
    parser.add_argument("--record", type=Path, required=True, help="where to write the record")
    add_imagery_option_argument(
        parser, "the NeRF half from the imagery fitted with this setting (repeatable; default: [])"
    )
    args = parser.parse_args(argv)
    options = dict(args.imagery_option)
    if args.colour_blur < 0:
        parser.error(f"--colour-blur: a sigma is at least 0 pixels, got {args.colour_blur}")
    if args.colour == args.height and not args.colour_blur:
        parser.error(
            "--colour and --height name the same imagery: that is a plain test (or give "
            "--colour-blur)"
        )
    blur = f"-blur{args.colour_blur:g}" if args.colour_blur else ""
    swap_dir = (
        args.swap_cache
        / f"{args.colour}-colour{blur}-{args.height}-height{imagery_options_suffix(options)}"
    )
    try:
        [(_, checkpoint)] = chosen_checkpoints(args.run_dir, [args.checkpoint])
        _, datamodule = load_checkpoint(checkpoint, torch.device("cpu"))
        specs = {
            kind: EvaluationSpec.from_datamodule(
                datamodule,
                split="test",
                setting=args.setting,
                imagery=kind,
                imagery_options=options if kind == "nerf" else None,
                cache_dir=None,
            )
            for kind in IMAGERY_KINDS
        }
        seeds = [split_seed("test", index) for index in range(args.episodes)]
        build_swap_cache(
            specs,
            args.colour,
            args.height,
            seeds,
            ImageryCache(args.cache_dir),
            ImageryCache(swap_dir),
            args.colour_blur,
        )
        [record] = evaluate_checkpoints(
            args.run_dir,
            "test",
            args.episodes,
            imagery="nerf",
            setting=args.setting,
            cache_dir=str(swap_dir),
            device=torch.device("cpu"),
            workers=args.eval_workers,
            only=[checkpoint],
            imagery_options=options or None,
        )
    except (FileNotFoundError, ValueError) as error:
        print(f"imagery_swap: {error}", file=sys.stderr)
        return 1
    record["imagery_swap"] = {"colour": args.colour, "height": args.height}
    if args.colour_blur:
        record["imagery_swap"]["colour_blur_px"] = args.colour_blur
    if options:
        record["imagery_swap"]["imagery_options"] = options
    write_json(args.record, record)
    print(
        f"{record['successes']}/{record['episodes']} succeeded (strict "
        f"{record['strict_successes']}), {record['errors']} erred: {args.record}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
