"""Where a result was made: the code's commit, and the machines a run was fitted on."""

from __future__ import annotations

import hashlib
import json
import subprocess
from pathlib import Path
from typing import Any

SEGMENTS = "fit-segments.json"  # in a run folder: one entry per fit started there


def _git(*args: str) -> str | None:
    """A git command's output in the package's checkout (stripped); None where it fails."""
    root = Path(__file__).resolve().parent
    try:
        result = subprocess.run(
            ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=60
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return result.stdout.strip() if result.returncode == 0 else None


def git_state() -> dict[str, Any]:
    """{"commit": HEAD of the package's checkout, "dirty": tracked files changed}; None each
    outside a git checkout."""
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"commit": commit, "dirty": None if status is None else bool(status)}


def code_identity() -> dict[str, Any]:
    """`git_state`, and for a dirty checkout the hash of its changes to tracked files
    ("diff_sha256"): two runs of the same identity ran the same code."""
    state = git_state()
    if state["dirty"]:
        diff = _git("diff", "HEAD", "--no-ext-diff", "--binary") or ""
        state["diff_sha256"] = hashlib.sha256(diff.encode()).hexdigest()
    return state


def read_segments(run_dir: Path) -> list[dict[str, Any]]:
    """The fits started in a run folder (`SEGMENTS`, written by run-cell): start, commit, machine
    and wall-clock time of each; [] for a run fitted otherwise (`lightning fit`)."""
    path = run_dir / SEGMENTS
    return json.loads(path.read_text()) if path.exists() else []
