"""`nerf-transporter cache-imagery`: a split's imagery is built once into the cache the episodes
read, under the key of the resolved config, and a second run builds nothing."""

from pathlib import Path

import pytest

from nerf_transporter.experiments import cache_imagery

REPO = Path(__file__).resolve().parents[2]
TINY = """data:
  init_args: {pixel_size: 0.0625, n_rotations: 4}
"""


def test_a_split_is_built_once_then_read(tmp_path, capsys):
    overlay = tmp_path / "tiny.yaml"
    overlay.write_text(TINY)
    argv = ["--task", "block-insertion", "--imagery", "oracle", "--split", "validation"]
    argv += ["--episodes", "2", "--reverse", "--config", str(overlay), "--no-progress"]
    argv += ["--configs", str(REPO / "configs"), "--cache-dir", str(tmp_path / "cache")]
    assert cache_imagery.main(argv) == 0
    assert "validation imagery (oracle): 2 of 2 seeds built" in capsys.readouterr().out
    files = sorted(path.name.split("-")[0] for path in (tmp_path / "cache").rglob("*.npz"))
    assert files == ["1000000", "1000001"]  # the first two validation seeds
    assert cache_imagery.main(argv) == 0
    assert "0 of 2 seeds built" in capsys.readouterr().out


def test_the_challenging_test_of_a_normal_fit_is_built_under_its_own_setting(tmp_path, capsys):
    """`--test-setting` resolves the Normal config, as `run-cell --test-setting` does, and builds
    the Challenging test scenes (no Challenging config of the task is needed)."""
    overlay = tmp_path / "tiny.yaml"
    overlay.write_text(TINY)
    argv = ["--task", "hanging-disks", "--imagery", "oracle", "--split", "test"]
    argv += ["--test-setting", "challenging", "--episodes", "1", "--config", str(overlay)]
    argv += ["--configs", str(REPO / "configs"), "--cache-dir", str(tmp_path / "cache")]
    assert not (REPO / "configs" / "hanging_disks_challenging.yaml").exists()
    assert cache_imagery.main([*argv, "--no-progress"]) == 0
    assert "hanging-disks-challenging test imagery (oracle): 1 of 1" in capsys.readouterr().out
    (built,) = (tmp_path / "cache").rglob("*.npz")
    assert built.parent.name == "hanging-disks-challenging" and built.name.startswith("1-")


def test_bad_requests_are_refused_with_the_reason(tmp_path, capsys):
    argv = ["--task", "block-insertion", "--setting", "challenging", "--configs", str(tmp_path)]
    assert cache_imagery.main(argv) == 2
    assert "no config " + str(tmp_path / "block_insertion_challenging.yaml") in (
        capsys.readouterr().err
    )
    with pytest.raises(SystemExit):
        cache_imagery.main(["--task", "block-insertion", "--episodes", "0"])
    assert "--episodes must be >= 1, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cache_imagery.main(
            ["--task", "block-insertion", "--split", "validation"]
            + ["--test-setting", "challenging"]
        )
    assert "--test-setting is the test split's" in capsys.readouterr().err
    argv = ["--task", "block-insertion", "--configs", str(REPO / "configs")]
    assert cache_imagery.main([*argv, "--also-render", "depth=median,iterations=800"]) == 2
    assert "iterations changes the fit, not its rendering" in capsys.readouterr().err
    assert cache_imagery.main([*argv, "--imagery", "oracle", "--also-render", "depth=median"]) == 2
    assert "rendering options set NeRF imagery's" in capsys.readouterr().err
