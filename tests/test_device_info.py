from importlib import metadata

import cv2
import torch

from nerf_transporter.device_info import describe_device, device_line


def test_describe_device_records_the_versions_a_cell_depends_on() -> None:
    info = describe_device("cpu")
    assert info["torch"] == torch.__version__
    assert info["opencv"] == cv2.__version__
    assert info["pybullet"] == metadata.version("pybullet")
    assert info["gpu"] is None
    assert info["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert info["threads"] == torch.get_num_threads()
    assert device_line(info).startswith(f"CPU {info['cpu']}, {info['threads']} threads")
