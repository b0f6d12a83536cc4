"""nerf-transporter: training sub-commands (fit, validate, test) run LightningCLI;
the others (oracle, generate, dataset-info, report, ...) are tools around it."""

from __future__ import annotations

import importlib
import os
import sys

# sub-command -> ("module:function", one-line help). Each function takes argv and returns an exit code.
TOOLS: dict[str, tuple[str, str]] = {
    "oracle": (
        "nerf_transporter.sim.oracle_cli:main",
        "run oracle episodes, print the success rate",
    ),
    "generate": (
        "nerf_transporter.data.generate:main",
        "oracle demonstrations -> episodes on disk",
    ),
    "dataset-info": (
        "nerf_transporter.data.info:main",
        "episodes, seeds, imagery quality (--verify)",
    ),
    "report": ("nerf_transporter.experiments.report:main", "results table (markdown or --csv)"),
    "try": (
        "nerf_transporter.experiments.pretrained:try_main",
        "run a shipped pretrained policy on a few test episodes, write videos",
    ),
    "export-pretrained": (
        "nerf_transporter.experiments.pretrained:export_main",
        "reduce a trained checkpoint to a shipped pretrained policy",
    ),
    "run-cell": (
        "nerf_transporter.experiments.run_cell:main",
        "one cell of the results table: fit, pick by validation, test, write its JSON",
    ),
    "cache-imagery": (
        "nerf_transporter.experiments.cache_imagery:main",
        "build a split's evaluation imagery (NeRF fits) into the cache before its episodes run",
    ),
    "failures": (
        "nerf_transporter.experiments.failures:main",
        "why the cells' test episodes failed: pick, aim (position / tilt / yaw) or settling",
    ),
    "compare-cells": (
        "nerf_transporter.experiments.compare:main",
        "cells tested alike (trained in either setting), paired on common seeds: McNemar p",
    ),
    "evaluate-checkpoints": (
        "nerf_transporter.experiments.checkpoints:main",
        "closed-loop success of every checkpoint of a run, to pick the one to test",
    ),
    "world": (
        "nerf_transporter.sim.fingerprint:main",
        "this package's world fingerprint, component by component (--json)",
    ),
}


# Sub-commands handed to LightningCLI (also what the `lightning` console script runs).
LIGHTNING_COMMANDS: dict[str, str] = {
    "fit": "train a method (LightningCLI; e.g. --config configs/block_insertion.yaml)",
    "validate": "validation losses of a checkpoint (LightningCLI)",
    "test": "closed-loop evaluation of a checkpoint (LightningCLI)",
}


def _usage() -> str:
    commands = list(LIGHTNING_COMMANDS.items())
    commands += [(name, help_text) for name, (_, help_text) in sorted(TOOLS.items())]
    width = max(len(name) for name, _ in commands) + 2
    lines = ["usage: nerf-transporter <command> [options]", "", "commands:"]
    lines += [f"  {name:<{width}}{help_text}" for name, help_text in commands]
    lines.append("\nRun `nerf-transporter <command> --help` for the options of one command.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    command, rest = argv[0], argv[1:]
    if command in LIGHTNING_COMMANDS or command == "predict":  # predict: refused, saying why
        return lightning_main(argv)
    if command not in TOOLS:
        print(f"nerf-transporter: unknown command {command!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, function_name = TOOLS[command][0].split(":")
    function = getattr(importlib.import_module(module_name), function_name)
    try:
        return int(function(rest) or 0)
    except BrokenPipeError:  # the reader left (`| head`): stop quietly, as a pipeline expects
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


def lightning_main(args: list[str] | None = None) -> int:
    """The `lightning` console script: `lightning fit|validate|test ...`
    (`experiments.lightning_cli`)."""
    from nerf_transporter.experiments.lightning_cli import main as lightning

    return lightning(args)


if __name__ == "__main__":
    sys.exit(main())
