"""`nerf-transporter oracle`: per-episode lines, the JSON summary, a watchable video, bad input."""

import json

import imageio.v2 as imageio
import pytest

from nerf_transporter.sim.oracle_cli import main


def test_episode_lines_json_summary_and_mp4_video(tmp_path, capsys):
    video = tmp_path / "episode.mp4"
    argv = ["--task", "block-insertion", "--episodes", "2", "--seed", "100001", "--json"]
    assert main([*argv, "--video", str(video)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split(":")[0] for line in lines[:2]] == [
        "episode 0 seed 100001",
        "episode 1 seed 100002",
    ]
    summary = json.loads(lines[-1])
    assert summary == {
        "task": "block-insertion",
        "setting": "normal",
        "episodes": 2,
        "successes": summary["successes"],
        "success_rate": summary["successes"] / 2,
    }
    reader = imageio.get_reader(video)
    assert reader.get_meta_data()["codec"] == "h264"
    assert sum(1 for _ in reader) > 20  # the arm moves through the whole episode
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--task", "block-stacking"], "block-insertion"),
        (["--task", "block-insertion", "--setting", "hard"], "challenging"),
        (["--task", "block-insertion", "--video", "episode.avi"], ".mp4 or .gif"),
        (["--task", "block-insertion", "--episodes", "0"], "at least 1"),
    ],
)
def test_bad_input_exits_2_with_a_clear_message(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err
