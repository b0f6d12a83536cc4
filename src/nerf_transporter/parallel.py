"""Worker processes shared by data generation and evaluation.

Workers are started with `spawn` (a fork would inherit PyBullet clients and torch's thread pools),
set their torch thread count, and die with the process that started them, even when it is killed
with SIGKILL (Linux's parent-death signal).
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import multiprocessing
import os
import signal
import sys

PR_SET_PDEATHSIG = 1  # prctl option (linux/prctl.h): signal this process when its parent dies
# In a worker process: the process that started it.
_PARENT_PID: int | None = None


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask, e.g. under `taskset` or a container)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def share_cores(jobs: int, workers: int | None = None, processes: int = 1) -> tuple[int, int]:
    """(worker processes, torch threads per worker) for `jobs` jobs of a process that shares the
    machine's cores with `processes - 1` others like it (DDP ranks on one node).

    `workers` defaults to this process's share of the cores; there are never more workers than
    jobs, and at least one. The threads split that share among the workers."""
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if processes < 1:
        raise ValueError(f"processes must be >= 1, got {processes}")
    share = max(1, available_cores() // processes)
    count = max(1, min(workers or share, jobs))
    return count, max(1, share // count)


def exit_if_orphaned() -> None:
    """In a worker process: end now if the process that started it is gone."""
    if _PARENT_PID is not None and os.getppid() != _PARENT_PID:
        os._exit(1)


def _init_worker(threads: int, parent: int) -> None:
    """Worker set-up: torch threads, and dying with the process that started it."""
    global _PARENT_PID
    import torch

    torch.set_num_threads(threads)
    _PARENT_PID = parent
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    exit_if_orphaned()  # the parent may have died before the death signal was set


def process_pool(workers: int, threads: int | None = None) -> cf.ProcessPoolExecutor:
    """A pool of `workers` spawned processes with `threads` torch threads each (default: the
    available cores shared among them) that die with this process.

    Submit from the thread that will outlive the pool (the main thread): the death signal is tied
    to the thread that starts a worker."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if threads is None:
        threads = max(1, available_cores() // workers)
    return cf.ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(threads, os.getpid()),
    )
