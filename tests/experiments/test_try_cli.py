"""`nerf-transporter try` succeeding: a shipped policy's episode, its lines, its video."""

from nerf_transporter.experiments.pretrained import try_main


def test_try_runs_a_shipped_policy_and_says_what_it_did(tmp_path, monkeypatch, capsys, one_thread):
    """block-insertion transporter_se2 solves test seed 1 (as in its cell): one line per episode,
    the rate with its interval, where the video went; exit status 0."""
    monkeypatch.chdir(tmp_path)
    video = tmp_path / "videos"
    argv = ["--task", "block-insertion", "--method", "transporter_se2", "--episodes", "1"]
    assert try_main([*argv, "--video", str(video), "--eval-workers", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "seed 1: success"
    assert lines[1].startswith("block-insertion transporter_se2: 100% (1, 21-100) in ")
    assert lines[2] == f"videos: 1 of 1 episodes in {video}/"
    assert len(lines) == 3
    (mp4,) = video.glob("*.mp4")
    assert mp4.name == "block-insertion-normal-seed1-transporter_se2.mp4"
    assert mp4.stat().st_size > 10_000
    assert sorted(path.name for path in tmp_path.iterdir()) == ["videos"]  # nothing else written
