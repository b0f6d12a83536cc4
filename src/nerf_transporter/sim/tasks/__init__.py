"""Task registry: task name -> Task class (see tasks/base.py for how to add one)."""

from nerf_transporter.sim.tasks.base import (
    POSE_ERROR_KEYS,
    SETTINGS,
    Task,
    Tolerance,
    pose_error_text,
)
from nerf_transporter.sim.tasks.block_insertion import BlockInsertion
from nerf_transporter.sim.tasks.hanging_disks import HangingDisks
from nerf_transporter.sim.tasks.place_red_in_green import PlaceRedInGreen
from nerf_transporter.sim.tasks.stacking_kits import StackingKits

TASKS: dict[str, type[Task]] = {
    "block-insertion": BlockInsertion,
    "place-red-in-green": PlaceRedInGreen,
    "hanging-disks": HangingDisks,
    "stacking-kits": StackingKits,
}

__all__ = ["POSE_ERROR_KEYS", "SETTINGS", "TASKS", "Task", "Tolerance", "pose_error_text"]
