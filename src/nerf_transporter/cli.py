"""nerf-transporter: training sub-commands (fit, validate, test, predict) run LightningCLI;
the others (oracle, generate, dataset-info, report, ...) are tools around it."""

from __future__ import annotations

import importlib
import sys
from typing import Any

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
    "report": ("nerf_transporter.evaluation.report:main", "results table (markdown or --csv)"),
    "evaluate-checkpoints": ("nerf_transporter.evaluation.checkpoints:main", "rank checkpoints"),
}


# Sub-commands handed to LightningCLI (also what the `lightning` console script runs).
LIGHTNING_COMMANDS: dict[str, str] = {
    "fit": "train a method (LightningCLI; e.g. --config configs/block_insertion.yaml)",
    "validate": "validation losses of a checkpoint (LightningCLI)",
    "test": "closed-loop evaluation of a checkpoint (LightningCLI)",
    "predict": "predictions of a checkpoint (LightningCLI)",
}


def _usage() -> str:
    lines = ["usage: nerf-transporter <command> [options]", "", "commands:"]
    for name, help_text in LIGHTNING_COMMANDS.items():
        lines.append(f"  {name:<14}{help_text}")
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
    if command in LIGHTNING_COMMANDS:
        return lightning_main(argv)
    if command not in TOOLS:
        print(f"nerf-transporter: unknown command {command!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name, function_name = TOOLS[command][0].split(":")
    function = getattr(importlib.import_module(module_name), function_name)
    return int(function(rest) or 0)


def run_name(model: Any, datamodule: Any) -> str:
    """`<task>/<method>` (task suffixed with its setting unless Normal): the TensorBoard run name."""
    task = str(getattr(datamodule, "task", None) or "unknown-task")
    setting = getattr(datamodule, "setting", "normal")
    if setting and setting != "normal":
        task = f"{task}-{setting}"
    return f"{task}/{getattr(model, 'name', type(model).__name__.lower())}"


def build_cli(args: list[str] | None = None, run: bool = True) -> Any:
    """LightningCLI (omegaconf parser mode): `model` is any `Method`, `data` any LightningDataModule.

    Without an explicit `trainer.logger`, runs log with TensorBoard to `logs/<task>/<method>/version_N`
    and checkpoints go to `checkpoints/` inside that folder. Returns the `LightningCLI` object.
    """
    import lightning.pytorch as pl
    from lightning.pytorch.cli import LightningCLI
    from lightning.pytorch.loggers import TensorBoardLogger

    from nerf_transporter.methods import Method

    class NerfTransporterCLI(LightningCLI):
        def instantiate_trainer(self, **kwargs: Any) -> pl.Trainer:
            logger = self._get(self.config_init, "trainer", default={}).get("logger")
            if logger is None or logger is True:
                kwargs["logger"] = TensorBoardLogger(
                    save_dir="logs", name=run_name(self.model, self.datamodule)
                )
            return super().instantiate_trainer(**kwargs)

    return NerfTransporterCLI(
        Method,
        pl.LightningDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        parser_kwargs={"parser_mode": "omegaconf"},
        save_config_kwargs={"overwrite": True},
        args=args,
        run=run,
    )


def lightning_main(args: list[str] | None = None) -> int:
    """The `lightning` console script: `lightning fit|validate|test|predict ...`."""
    build_cli(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
