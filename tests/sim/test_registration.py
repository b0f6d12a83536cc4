"""The tasks as gymnasium environments: registered ids, `gymnasium.make` options, the env checker."""

import os
import sys

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.passive_env_checker import env_render_passive_checker

import nerf_transporter  # noqa: F401  (registers the ids)
from nerf_transporter.sim import TASKS
from nerf_transporter.sim.registration import TASK_NAMES, env_id
from tests.helpers.fresh_python import run_python

# check_env makes the environment once per render mode; "human" opens PyBullet's GUI window.
HAS_DISPLAY = bool(os.environ.get("DISPLAY"))


def test_one_id_per_task():
    assert tuple(TASKS) == TASK_NAMES
    for task in TASKS:
        assert gymnasium.spec(env_id(task)).kwargs == {"task": task}


@pytest.mark.parametrize("task", TASK_NAMES)
def test_every_registered_id_passes_the_env_checker(task):
    env = gymnasium.make(env_id(task), render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=not HAS_DISPLAY)
    env.reset(seed=0)
    env_render_passive_checker(env)
    frame = env.render()
    assert frame.dtype == np.uint8
    assert frame.ndim == 3
    assert frame.shape[2] == 3
    env.close()


def test_make_passes_options_to_the_environment():
    env = gymnasium.make(
        env_id("place-red-in-green"),
        setting="challenging",
        rigs=("state", "nerf"),
        nerf_views=2,
        nerf_image_size=(24, 32),
    )
    obs, _ = env.reset(seed=1)
    assert env.unwrapped.task.setting == "challenging"
    assert obs["nerf"]["rgb"].shape == (2, 24, 32, 3)
    assert env.observation_space.contains(obs)
    env.close()


def test_module_prefix_registers_the_ids_in_a_fresh_interpreter():
    code = (
        "import gymnasium\n"
        "env = gymnasium.make('nerf_transporter:nerf_transporter/block-insertion-v0')\n"
        "print(env.spec.id, env.unwrapped.task.name)\n"
    )
    result = run_python("-c", code, timeout=120)
    assert result.stdout.split() == ["nerf_transporter/block-insertion-v0", "block-insertion"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="DISPLAY is how Linux finds one")
def test_human_mode_without_a_display_is_a_clear_error(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(RuntimeError, match="needs a display"):
        gymnasium.make(env_id("block-insertion"), render_mode="human")
