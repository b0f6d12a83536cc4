"""The simulator plays the committed trace (sim/world_trace.json) the world fingerprint hashes."""

import copy
import os
import subprocess
import sys

from nerf_transporter.sim import fingerprint, trace

# An episode whose contacts amplify a last-bit difference in a commanded pose into another
# settled scene (as numpy's BLAS kernels once made it, CPU by CPU), played at full precision.
_FULL_PRECISION_EPISODE = (
    "import json, sys\n"
    "from nerf_transporter.sim import trace\n"
    "trace.DECIMALS = 17\n"
    "json.dump(trace.episode_trace('place-red-in-green', 'challenging'), sys.stdout)\n"
)


def test_the_simulator_plays_the_committed_trace():
    """Fails on a change of behaviour until `python -m nerf_transporter.sim.trace --write`."""
    assert trace.differences(fingerprint.committed_trace(), trace.world_trace()) == []


def test_the_world_plays_the_same_bits_whatever_blas_kernel_numpy_runs():
    """The world's arithmetic goes through no BLAS (geometry.py, "Arithmetic the same on every
    CPU"): OpenBLAS's kernel for an older CPU (OPENBLAS_CORETYPE=Nehalem) instead of this CPU's
    own changes no bit of an episode (it moved this one's settled poses by up to 0.006 before)."""
    environment = {key: value for key, value in os.environ.items() if key != "OPENBLAS_CORETYPE"}
    played = [
        subprocess.run(
            [sys.executable, "-c", _FULL_PRECISION_EPISODE],
            env={**environment, **kernel, "OMP_NUM_THREADS": "1"},
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        for kernel in ({}, {"OPENBLAS_CORETYPE": "Nehalem"})
    ]
    assert '"settled"' in played[0]
    assert played[0] == played[1]


def test_a_real_change_is_a_difference_and_float_noise_is_not():
    committed = fingerprint.committed_trace()
    episode = "block-insertion/normal"
    noisy = copy.deepcopy(committed)
    noisy["episodes"][episode]["settled"][2][0] += trace.TOLERANCE / 2
    assert trace.differences(committed, noisy) == []
    moved = copy.deepcopy(committed)
    moved["episodes"][episode]["settled"][2][0] += 0.001  # a millimetre
    assert trace.differences(committed, moved) == [
        f"trace.episodes.{episode}.settled[2][0]: committed "
        f"{committed['episodes'][episode]['settled'][2][0]!r}, replayed "
        f"{moved['episodes'][episode]['settled'][2][0]!r}"
    ]
    rebuilt = copy.deepcopy(committed)
    rebuilt["episodes"][episode]["assets"][0] = "ell.urdf 000000000000"
    assert len(trace.differences(committed, rebuilt)) == 1
    failed = copy.deepcopy(committed)
    failed["episodes"][episode]["outcome"]["success"] = False
    assert len(trace.differences(committed, failed)) == 1
