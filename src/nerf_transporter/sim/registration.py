"""Gymnasium ids `nerf_transporter/<task>-v0`, one per task, registered on `import nerf_transporter`.

    import gymnasium
    import nerf_transporter  # registers the ids

    env = gymnasium.make("nerf_transporter/block-insertion-v0", setting="challenging")
    env = gymnasium.make("nerf_transporter:nerf_transporter/block-insertion-v0")  # imports it first

Keyword arguments of `gymnasium.make` go to `nerf_transporter.sim.make_env` (`setting`, `rigs`,
`nerf_views`, `nerf_image_size`, `render_mode`, `nerf_show_robot`, `nerf_cameras`). This module
imports neither PyBullet nor the task classes, so that importing the package stays cheap:
`TASK_NAMES` repeats the keys of `nerf_transporter.sim.TASKS` (tests/sim/test_registration.py
checks that they agree).
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

NAMESPACE = "nerf_transporter"
VERSION = 0
ENTRY_POINT = "nerf_transporter.sim.env:make_env"
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
