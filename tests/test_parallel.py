"""Worker processes: how cores are shared out, and workers that die with their parent."""

import os
import signal
import subprocess
import sys
import time

import pytest

from nerf_transporter import parallel


def test_cores_are_shared_among_workers_and_ranks(monkeypatch):
    monkeypatch.setattr(parallel, "available_cores", lambda: 16)
    assert parallel.share_cores(100) == (16, 1)
    assert parallel.share_cores(3) == (3, 5)  # never more workers than jobs
    assert parallel.share_cores(1) == (1, 16)
    assert parallel.share_cores(100, workers=4) == (4, 4)
    assert parallel.share_cores(100, processes=2) == (8, 1)  # two DDP ranks on the machine
    assert parallel.share_cores(100, workers=2, processes=4) == (2, 2)
    with pytest.raises(ValueError, match="workers must be >= 1, got 0"):
        parallel.share_cores(10, workers=0)


WORKER_PROBE = """
import os, time
from nerf_transporter.parallel import process_pool
pool = process_pool(2)
print(pool.submit(os.getpid).result(), flush=True)
time.sleep(60)
"""


def _process_running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rpartition(")")[2].split()[0] != "Z"  # a zombie has ended
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signal is Linux's")
def test_workers_die_with_a_killed_parent():
    parent = subprocess.Popen([sys.executable, "-c", WORKER_PROBE], stdout=subprocess.PIPE)
    worker = int(parent.stdout.readline())
    try:
        assert _process_running(worker)
        parent.kill()  # SIGKILL: no clean-up in the parent
        parent.wait()
        deadline = time.monotonic() + 10
        while _process_running(worker) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _process_running(worker)
    finally:
        if _process_running(worker):
            os.kill(worker, signal.SIGKILL)
        parent.stdout.close()
