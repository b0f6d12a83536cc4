"""`nerf-transporter oracle`: per-episode lines, the JSON summary, a watchable video, bad input,
`--help`, and no PyBullet banner in the output."""

import json

import imageio.v2 as imageio
import numpy as np
import pytest

from nerf_transporter.sim.oracle_cli import main
from nerf_transporter.sim.tasks import TASKS
from tests.helpers.fresh_python import run_python


def test_episode_lines_json_summary_and_mp4_video(tmp_path, capsys, monkeypatch):
    """Two oracle episodes (both succeed by both checks on these seeds), the second one's place
    moved 10 cm off its target: the lines and the summary count one success of two."""
    task = TASKS["block-insertion"]
    oracle = task.oracle

    def missing_the_second(self, env):
        action = oracle(self, env)
        if env.np_random_seed == 100002:
            position, quat = action["place"]
            action["place"] = (np.asarray(position) + [0.0, 0.1, 0.0], quat)
        return action

    monkeypatch.setattr(task, "oracle", missing_the_second)
    video = tmp_path / "episode.mp4"
    argv = ["--task", "block-insertion", "--episodes", "2", "--seed", "100001", "--json"]
    assert main([*argv, "--video", str(video)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split(":")[0] for line in lines[:2]] == [
        "episode 0 seed 100001",
        "episode 1 seed 100002",
    ]
    assert "success=True reward=1 strict_success=True" in lines[0]
    assert "success=False reward=0 strict_success=False" in lines[1]
    assert json.loads(lines[-1]) == {
        "task": "block-insertion",
        "setting": "normal",
        "episodes": 2,
        "successes": 1,
        "success_rate": 0.5,
        "strict_successes": 1,
        "strict_success_rate": 0.5,
    }
    reader = imageio.get_reader(video)
    assert reader.get_meta_data()["codec"] == "h264"
    assert sum(1 for _ in reader) > 20  # the arm moves through the whole episode
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--task", "block-insertion", "--video", "episode.avi"], ".mp4 or .gif"),
        (["--task", "block-insertion", "--episodes", "0"], "at least 1"),
    ],
)
def test_bad_input_exits_2_with_a_clear_message(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--task", "block-stacking"], "block-insertion"),
        (["--task", "block-insertion", "--setting", "hard"], "challenging"),
    ],
)
def test_unknown_task_or_setting_exits_2_listing_the_choices(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_help_shows_choices_and_defaults(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "{block-insertion,hanging-disks,place-red-in-green,stacking-kits}" in text
    assert "{normal,challenging,flat}" in text
    assert "(default: normal)" in text
    assert "(default: 10)" in text


def test_no_pybullet_banner_in_the_output():
    """PyBullet prints its build time on import and its argv on connect unless silenced."""
    result = run_python(
        "-m", "nerf_transporter.cli", "oracle", "--episodes", "1", "--task", "block-insertion"
    )
    assert "block-insertion normal: " in result.stdout
    for output in (result.stdout, result.stderr):
        assert "argv[0]=" not in output
        assert "pybullet build time" not in output
