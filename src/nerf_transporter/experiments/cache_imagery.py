"""`nerf-transporter cache-imagery --task T [--setting S] [--split test] [--episodes 100]`: build the
evaluation imagery of a split's first seeds into the imagery cache before any episode runs.

A mira test episode spends most of its time fitting its scene's NeRF. The fit depends on the scene
only, not on the policy, so it can run on a free core while the policy still trains, and the
episodes later only read the cache (`evaluation/cache.py`). The imagery is looked up as the
episodes of `run-cell` look it up: task, setting, seed and the imagery config of the same resolved
config (the task's, then any `--config` overlays). As in `run-cell`, `--setting` names the setting
trained in, whose config is resolved, and `--test-setting` the one a test split runs in: the
Challenging test of a Normal fit is `--test-setting challenging`. Seeds already cached are
skipped, so an interrupted run resumes; `--reverse` starts at the last seed, so that it meets a test run going
forward instead of building the same scenes at the same time.
`--also-render depth=median` caches each scene's imagery rendered that way too, from the same fit
(a rendering option changes no fit: `imagery.RENDER_OPTIONS`), where `evaluate-checkpoints
--imagery-option depth=median` reads it.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

from nerf_transporter.console import HelpFormatter, progress_bar
from nerf_transporter.data.datamodule import RavensDataModule
from nerf_transporter.data.generate import imagery_option
from nerf_transporter.evaluation.rollout import DEFAULT_CACHE_DIR, EvaluationSpec, Evaluator
from nerf_transporter.experiments.run_cell import (
    CellError,
    add_config_arguments,
    config_files,
    resolve_config,
)
from nerf_transporter.imagery import RENDER_OPTIONS
from nerf_transporter.sim.registration import TASK_NAMES
from nerf_transporter.sim.tasks import SETTINGS
from nerf_transporter.splits import split_seed


def imagery_spec(
    config: dict[str, Any],
    split: str,
    imagery: str | None,
    cache_dir: str,
    test_setting: str | None = None,
) -> EvaluationSpec:
    """The evaluation spec of `split` for the RavensDataModule that `config` trains on, in
    `test_setting` (default: the config's) where the split is the test split."""
    data = config.get("data") or {}
    if not str(data.get("class_path", "")).endswith("RavensDataModule"):
        raise CellError(f"the config's data is {data.get('class_path')}, not a RavensDataModule")
    datamodule = RavensDataModule(**data.get("init_args", {}))
    return EvaluationSpec.from_datamodule(
        datamodule, split=split, setting=test_setting, imagery=imagery, cache_dir=cache_dir
    )


def cache_imagery(
    spec: EvaluationSpec,
    seeds: list[int],
    renderings: Sequence[dict[str, Any]] = (),
    progress: bool = True,
) -> tuple[int, float]:
    """Build the imagery of each seed missing from the cache, and with `renderings` that imagery
    rendered with each of these rendering options from the same fit (`Evaluator.cache_imagery`);
    (seeds built, seconds taken)."""
    built, start = 0, time.perf_counter()
    with (
        Evaluator(spec) as evaluator,
        progress_bar(len(seeds), f"imagery {spec.task}-{spec.setting}", enabled=progress) as bar,
    ):
        for seed in seeds:
            built += evaluator.cache_imagery(seed, renderings) > 0
            bar.set_postfix(built=built)
            bar.update(1)
    return built, time.perf_counter() - start


def rendering(text: str) -> dict[str, Any]:
    """`--also-render KEY=VALUE[,KEY=VALUE]` -> the rendering's options."""
    return dict(imagery_option(pair) for pair in text.split(","))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="nerf-transporter cache-imagery",
        description="Build the evaluation imagery (the NeRF fit of each scene) of a split's first "
        "seeds into the imagery cache, e.g. on a free core while the policy trains, so that "
        "validation and test episodes only read it. Resumable: cached seeds are skipped.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--task", required=True, choices=TASK_NAMES)
    parser.add_argument(
        "--setting", default="normal", choices=SETTINGS, help="the setting trained in"
    )
    parser.add_argument(
        "--test-setting",
        choices=SETTINGS,
        help="the setting the test split runs in, as run-cell's: e.g. challenging for the "
        "Challenging test of a Normal fit (default: --setting)",
    )
    parser.add_argument(
        "--imagery", choices=("nerf", "oracle"), help="default: the config's (nerf)"
    )
    parser.add_argument("--split", default="test", choices=("validation", "test"))
    parser.add_argument("--episodes", type=int, default=100, help="the split's first seeds")
    parser.add_argument(
        "--reverse", action="store_true", help="last seed first (to meet a run going forward)"
    )
    parser.add_argument(
        "--also-render",
        type=rendering,
        action="append",
        default=[],
        metavar="KEY=VALUE[,KEY=VALUE]",
        help="also cache each scene's NeRF imagery rendered with these rendering options, from "
        f"the same fit (repeatable, one rendering each; options: {', '.join(RENDER_OPTIONS)}), "
        "under the key `evaluate-checkpoints --imagery-option KEY=VALUE ...` reads: e.g. "
        "depth=median builds the default and the median-depth imagery for one fit's cost",
    )
    add_config_arguments(parser, "the task's, as given to run-cell")
    parser.add_argument("--cache-dir", default=DEFAULT_CACHE_DIR, help="imagery cache")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.split != "test" and args.test_setting not in (None, args.setting):
        parser.error(
            f"--test-setting is the test split's; the {args.split} split runs in --setting"
        )
    try:
        files = config_files(args.configs, args.task, args.setting, None) + args.config
        config = resolve_config(files)
        spec = imagery_spec(config, args.split, args.imagery, args.cache_dir, args.test_setting)
        for options in args.also_render:
            spec.scene.rendered_with(options)
    except (CellError, FileNotFoundError, ValueError) as error:
        print(f"nerf-transporter cache-imagery: {error}", file=sys.stderr)
        return 2
    seeds = [split_seed(args.split, index) for index in range(args.episodes)]
    if args.reverse:
        seeds.reverse()
    built, seconds = cache_imagery(spec, seeds, args.also_render, progress=not args.no_progress)
    also = "".join(
        ", also " + ",".join(f"{key}={value}" for key, value in options.items())
        for options in args.also_render
    )
    print(
        f"{spec.task}-{spec.setting} {args.split} imagery ({spec.imagery}{also}): {built} of "
        f"{len(seeds)} seeds built in {seconds:.0f} s, {len(seeds) - built} were cached, "
        f"under {args.cache_dir}"
    )
    return 0
