"""Run folders: `logs/<task>/<method>/version_N`, one per `lightning fit|validate|test|predict`
(TensorBoard's logs, `checkpoints/`, `config.yaml`, the test's `results-<checkpoint>.json`), claimed
atomically, resumed from their checkpoint of the highest step, and removed again where a failed
command left nothing in them. `lightning` and `run-cell` share them."""

from __future__ import annotations

import contextlib
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from nerf_transporter.experiments.cells import TEST_RECORD_GLOB
from nerf_transporter.experiments.checkpoints import checkpoint_steps

LOG_ROOT = Path("logs")
VERSION_FOLDER = re.compile(r"version_(\d+)")


def run_name(model: Any, datamodule: Any) -> str:
    """`<task>/<method>` (task suffixed with its setting unless Normal): the TensorBoard run name."""
    task = str(getattr(datamodule, "task", None) or "unknown-task")
    setting = getattr(datamodule, "setting", "normal")
    if setting and setting != "normal":
        task = f"{task}-{setting}"
    return f"{task}/{getattr(model, 'name', type(model).__name__.lower())}"


def _version(path: Path) -> int | None:
    match = VERSION_FOLDER.fullmatch(path.name)
    return int(match.group(1)) if match else None


def claim_version(runs: Path) -> int:
    """Create and return the next free `version_N` under `runs`. mkdir is atomic, so two runs
    started together never share a folder (one of them takes the next number)."""
    runs.mkdir(parents=True, exist_ok=True)
    taken = [number for path in runs.iterdir() if (number := _version(path)) is not None]
    version = max(taken, default=-1) + 1
    while True:
        try:
            (runs / f"version_{version}").mkdir()
            return version
        except FileExistsError:
            version += 1


class NoRunToResumeError(FileNotFoundError):
    """`--ckpt_path last` where the task and method have no run with a readable checkpoint."""


def latest_checkpoint(runs: Path) -> Path:
    """The checkpoint to resume from: in the highest-numbered run under `runs` with a readable
    checkpoint, the one of the highest global step, whatever its name (`last.ckpt` lags behind
    where Lightning wrote `last-v1.ckpt` in a moved run folder) or time (a copy from another
    machine can give every file the same time); an unreadable one (partly written, e.g. on a
    full disk) is skipped with a warning."""
    folders = list(runs.iterdir()) if runs.is_dir() else []
    numbered = [(number, path) for path in folders if (number := _version(path)) is not None]
    for _, path in sorted(numbered, reverse=True):
        if steps := checkpoint_steps(path / "checkpoints"):
            return steps[-1][1]
    raise NoRunToResumeError(
        f"--ckpt_path last: no earlier run to resume, no readable checkpoint under {runs}/"
        "version_N/checkpoints; start a new run without --ckpt_path"
    )


@contextlib.contextmanager
def removed_if_unused(claimed: list[Path]) -> Iterator[None]:
    """Where the block raises, remove the run folders in `claimed` that hold no checkpoint and no
    results file: a failed command leaves no `version_N` with nothing to resume or read."""
    try:
        yield
    except BaseException:
        for folder in claimed:
            if not any(folder.rglob("*.ckpt")) and not any(folder.rglob(TEST_RECORD_GLOB)):
                shutil.rmtree(folder, ignore_errors=True)
        raise


def run_folder(checkpoint: str) -> Path | None:
    """The run folder (`.../version_N`) whose `checkpoints/` holds a local checkpoint, if any."""
    path = Path(checkpoint)
    if (
        path.is_file()
        and path.parent.name == "checkpoints"
        and _version(path.parent.parent) is not None
    ):
        return path.parent.parent
    return None
