"""What a benchmark figure was measured on: CPU model, torch threads, torch version, GPU name."""

from __future__ import annotations

import platform
from pathlib import Path

import torch


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo, else `platform.processor()` or the architecture."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def describe_device(device: torch.device | str = "cpu") -> dict:
    """{"cpu", "threads", "torch", "gpu"}; "gpu" is the CUDA device's name, or None on CPU."""
    device = torch.device(device)
    return {
        "cpu": cpu_model(),
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(device) if device.type == "cuda" else None,
    }


def device_line(info: dict) -> str:
    """One printable line of `describe_device`'s output."""
    gpu = f", GPU {info['gpu']}" if info["gpu"] else ""
    return f"CPU {info['cpu']}, {info['threads']} threads, torch {info['torch']}{gpu}"
