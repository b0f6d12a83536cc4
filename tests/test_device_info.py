"""What a cell records of the machine it was measured on."""

from importlib import metadata

import pytest

from nerf_transporter import device_info
from nerf_transporter.device_info import cpu_model, describe_device, device_line, pybullet_version

CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
model name\t: AMD EPYC 7B13 64-Core Processor
flags\t\t: fpu avx2
"""


def test_the_cpu_model_is_read_from_cpuinfo(tmp_path, monkeypatch):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(CPUINFO)
    monkeypatch.setattr(device_info, "Path", lambda _: cpuinfo)
    assert cpu_model() == "AMD EPYC 7B13 64-Core Processor"


def test_without_cpuinfo_the_cpu_model_is_the_platforms(tmp_path, monkeypatch):
    monkeypatch.setattr(device_info, "Path", lambda _: tmp_path / "absent")
    monkeypatch.setattr(device_info.platform, "processor", lambda: "")
    monkeypatch.setattr(device_info.platform, "machine", lambda: "aarch64")
    assert cpu_model() == "aarch64"
    monkeypatch.setattr(device_info.platform, "processor", lambda: "arm")
    assert cpu_model() == "arm"


def test_a_missing_pybullet_is_recorded_as_none(monkeypatch):
    def absent(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(device_info.metadata, "version", absent)
    assert pybullet_version() is None


def test_a_cpu_description_has_the_fields_a_cell_records_and_no_gpu(one_thread):
    info = describe_device("cpu")
    assert set(info) == {"cpu", "cpu_capability", "threads", "torch", "opencv", "pybullet", "gpu"}
    assert info["gpu"] is None and info["threads"] == 1  # the threads in effect (one_thread)
    assert all(isinstance(info[key], str) and info[key] for key in ("cpu", "torch", "opencv"))


@pytest.mark.parametrize(
    ("gpu", "line"),
    [
        (None, "CPU AMD EPYC, 4 threads, torch 2.6.0"),
        ("NVIDIA H200", "CPU AMD EPYC, 4 threads, torch 2.6.0, GPU NVIDIA H200"),
    ],
)
def test_the_device_line_names_cpu_threads_torch_and_any_gpu(gpu, line):
    info = {"cpu": "AMD EPYC", "threads": 4, "torch": "2.6.0", "gpu": gpu}
    assert device_line(info) == line
