"""The PyBullet world: UR5e + suction, task families, camera rigs (see docs/interfaces.md).

`RavensEnv` and `make_env` are imported on first use, so that the parts of the world that need no
simulator (task registry, assets, the world fingerprint) import on machines without PyBullet.
"""

from __future__ import annotations

import importlib
from typing import Any

from nerf_transporter.sim.tasks import SETTINGS, TASKS

__all__ = ["SETTINGS", "TASKS", "RavensEnv", "make_env"]


def __getattr__(name: str) -> Any:
    if name in ("RavensEnv", "make_env"):
        return getattr(importlib.import_module("nerf_transporter.sim.env"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
