"""Run this checkout's code in a fresh interpreter (imports, banners and exit codes as a user sees
them)."""

import os
import subprocess
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[2] / "src"


def run_python(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """`python <args>` with this checkout's `src` on the path; fails the test on a non-zero exit."""
    result = subprocess.run(
        [sys.executable, *args],
        env={**os.environ, "PYTHONPATH": str(SRC)},
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    return result
