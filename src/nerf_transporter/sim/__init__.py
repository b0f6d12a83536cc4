"""The PyBullet world: UR5e + suction, task families, camera rigs (see docs/interfaces.md).

Everything here is imported on first use: `RavensEnv` and `make_env` so that the parts of the world
that need no simulator (task registry, assets, the world fingerprint) import on machines without
PyBullet, and `TASKS` / `SETTINGS` so that importing the package (which registers the gymnasium ids
of `sim.registration`) does not load every task module.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["SETTINGS", "TASKS", "RavensEnv", "make_env"]

_LAZY = {
    "RavensEnv": "nerf_transporter.sim.env",
    "make_env": "nerf_transporter.sim.env",
    "SETTINGS": "nerf_transporter.sim.tasks",
    "TASKS": "nerf_transporter.sim.tasks",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
