"""Fixtures shared by the tests."""

import pytest
import torch

from nerf_transporter.data import generate as gen
from tests.helpers.fake_sim import FakeEnv


@pytest.fixture(scope="module")
def one_thread():
    """One torch thread for a module: tiny convolutions run far faster on one thread than on two
    contended ones, and numbers do not depend on how reductions are split over threads."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def fake_world(monkeypatch):
    """Generation runs on the deterministic stand-in for the simulator (helpers.fake_sim)."""
    monkeypatch.setattr(gen, "_env", lambda config: FakeEnv())
