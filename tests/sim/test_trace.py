"""The simulator plays the committed trace (sim/world_trace.json) the world fingerprint hashes."""

import copy

from nerf_transporter.sim import fingerprint, trace


def test_the_simulator_plays_the_committed_trace():
    """Fails on a change of behaviour until `python -m nerf_transporter.sim.trace --write`."""
    assert trace.differences(fingerprint.committed_trace(), trace.world_trace()) == []


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
