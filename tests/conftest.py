"""Fixtures shared by the tests."""

from pathlib import Path

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


# What a Lightning trainer writes where no folder is named: a test must name one (tmp_path).
STRAY_OUTPUTS = tuple(Path.cwd() / name for name in ("checkpoints", "lightning_logs"))
STRAY_BEFORE_THE_SESSION = {path for path in STRAY_OUTPUTS if path.exists()}


@pytest.fixture(autouse=True)
def writes_nothing_into_the_working_directory():
    """Each test (and the fixtures it uses) leaves the working directory (the checkout, in CI) as
    the session found it."""
    yield
    stray = [str(p) for p in STRAY_OUTPUTS if p.exists() and p not in STRAY_BEFORE_THE_SESSION]
    assert not stray, f"the test or its fixtures wrote {stray}"
