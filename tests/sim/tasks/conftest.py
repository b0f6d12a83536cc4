import pytest

from nerf_transporter.sim import make_env


@pytest.fixture(scope="module")
def env(request):
    """The test module's TASK, Normal setting, reset to its ENV_SEED; shared by the module."""
    environment = make_env(request.module.TASK, "normal")
    environment.reset(seed=request.module.ENV_SEED)
    yield environment
    environment.close()
