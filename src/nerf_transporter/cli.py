"""nerf-transporter: training sub-commands (fit, validate, test, predict) run LightningCLI;
the others (oracle, generate, dataset-info, report, ...) are tools around it."""

from __future__ import annotations

import importlib
import sys

# sub-command -> ("module:function", one-line help). Each function takes argv and returns an exit code.
TOOLS: dict[str, tuple[str, str]] = {
    "oracle": ("nerf_transporter.sim.oracle_cli:main", "run oracle episodes, print the success rate"),
    "generate": ("nerf_transporter.data.generate:main", "oracle demonstrations -> episodes on disk"),
    "dataset-info": ("nerf_transporter.data.info:main", "episodes, seeds, imagery quality (--verify)"),
    "report": ("nerf_transporter.evaluation.report:main", "results table (markdown or --csv)"),
    "evaluate-checkpoints": ("nerf_transporter.evaluation.checkpoints:main", "rank checkpoints"),
}


def _usage() -> str:
    lines = ["usage: nerf-transporter <command> [options]", "", "commands:"]
    for name, (_, help_text) in sorted(TOOLS.items()):
        lines.append(f"  {name:<14}{help_text}")
    lines.append("\nRun `nerf-transporter <command> --help` for the options of one command.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    command, rest = argv[0], argv[1:]
    if command not in TOOLS:
        print(f"nerf-transporter: unknown command {command!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, function_name = TOOLS[command][0].split(":")
    function = getattr(importlib.import_module(module_name), function_name)
    return int(function(rest) or 0)


if __name__ == "__main__":
    sys.exit(main())
