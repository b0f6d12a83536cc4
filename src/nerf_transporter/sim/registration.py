"""Gymnasium ids `nerf_transporter/<task>-v0`, one per task, registered on `import nerf_transporter`.

    import gymnasium
    import nerf_transporter  # registers the ids

    env = gymnasium.make("nerf_transporter/block-insertion-v0", setting="challenging")
    env = gymnasium.make("nerf_transporter:nerf_transporter/block-insertion-v0")  # imports it first

Keyword arguments of `gymnasium.make` go to `nerf_transporter.sim.make_env` (`setting`, `rigs`,
`nerf_views`, `nerf_image_size`, `render_mode`, `nerf_show_robot`, `nerf_cameras`). The
environment comes in a `CheckedEnv`: an action holding anything but real numbers (complex, text,
booleans) and a reset after close are errors that say so. This module imports neither PyBullet nor
the task classes, so that importing the package stays cheap: `TASK_NAMES` repeats the keys of
`nerf_transporter.sim.TASKS` (tests/sim/test_registration.py checks that they agree).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium.envs.registration import register, registry

NAMESPACE = "nerf_transporter"
VERSION = 0
ENTRY_POINT = "nerf_transporter.sim.registration:make_checked_env"
REAL_KINDS = "iuf"  # numpy dtype kinds of a pose's numbers: integers and floats


class CheckedEnv(gymnasium.Wrapper):
    """A `RavensEnv` that names what it cannot take: an action pose holding other than real
    numbers (casting to float would drop a complex part, or read text as numbers), and a reset
    after `close()`."""

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        client = getattr(self.unwrapped, "client", None)
        if client is None or not client.isConnected():
            raise RuntimeError("reset() after close(): make a new environment")
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        for key, pose in action.items() if isinstance(action, Mapping) else ():
            try:
                parts = [np.asarray(part) for part in pose]
            except (TypeError, ValueError):
                continue  # no pose at all: the environment's own check names it
            for part in parts:
                if part.dtype.kind not in REAL_KINDS:
                    raise ValueError(
                        f"action[{key!r}] holds {part.dtype} values {part.tolist()!r:.80}; a pose "
                        "is real numbers (position [3], quaternion [4])"
                    )
        return self.env.step(action)


def make_checked_env(**kwargs: Any) -> CheckedEnv:
    """`nerf_transporter.sim.make_env(**kwargs)` in a `CheckedEnv` (the registered entry point)."""
    from nerf_transporter.sim.env import make_env

    return CheckedEnv(make_env(**kwargs))


TASK_NAMES = ("block-insertion", "place-red-in-green", "hanging-disks", "stacking-kits")


def env_id(task: str) -> str:
    """The gymnasium id of a task, e.g. `nerf_transporter/block-insertion-v0`."""
    return f"{NAMESPACE}/{task}-v{VERSION}"


def register_envs() -> list[str]:
    """Register every task's id (those already registered are left alone); returns the ids."""
    ids = [env_id(task) for task in TASK_NAMES]
    for task, id_ in zip(TASK_NAMES, ids, strict=True):
        if id_ not in registry:
            register(id=id_, entry_point=ENTRY_POINT, kwargs={"task": task})
    return ids
