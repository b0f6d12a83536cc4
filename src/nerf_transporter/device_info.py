"""What a figure was measured on: CPU model, torch threads, GPU name, and the versions that shape it."""

from __future__ import annotations

import platform
from importlib import metadata
from pathlib import Path

import cv2
import torch


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo, else `platform.processor()` or the architecture."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def pybullet_version() -> str | None:
    """The installed PyBullet's version, or None where it is absent (the GPU machine)."""
    try:
        return metadata.version("pybullet")
    except metadata.PackageNotFoundError:
        return None


def describe_device(device: torch.device | str = "cpu") -> dict:
    """{"cpu", "cpu_capability", "threads", "torch", "opencv", "pybullet", "gpu"}; "gpu" is None
    on CPU.

    OpenCV and PyBullet are recorded because they move figures: OpenCV's warps shape the
    augmented images, PyBullet is the world. "cpu_capability" is the instruction set torch's CPU
    kernels run with (AVX2, AVX512, ...): a fit is bit-for-bit repeatable only on the same one.
    """
    device = torch.device(device)
    return {
        "cpu": cpu_model(),
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "opencv": cv2.__version__,
        "pybullet": pybullet_version(),
        "gpu": torch.cuda.get_device_name(device) if device.type == "cuda" else None,
    }


def device_line(info: dict) -> str:
    """One printable line of `describe_device`'s output."""
    gpu = f", GPU {info['gpu']}" if info["gpu"] else ""
    return f"CPU {info['cpu']}, {info['threads']} threads, torch {info['torch']}{gpu}"
