import json
import os
import time

import numpy as np
import pytest

from nerf_transporter.data import episode as ep


def _arrays(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return {
        "rgbd": {
            "rgb": rng.integers(0, 255, (3, 8, 10, 3), dtype=np.uint8),
            "depth": rng.random((3, 8, 10), dtype=np.float32),
        },
        "imagery": {"colour": rng.integers(0, 255, (2, 8, 4, 3), dtype=np.uint8)},
    }


def test_write_list_load_verify(tmp_path):
    arrays = _arrays()
    path = ep.write_episode(tmp_path, 3, 6, {"task": "block-insertion"}, arrays)
    assert path.name == "000003-6"
    refs = ep.list_episodes(tmp_path)
    assert [(r.index, r.seed) for r in refs] == [(3, 6)]
    ep.verify_episode(path)
    episode = ep.load_episode(path, files=["rgbd"])
    assert episode.meta["task"] == "block-insertion" and episode.meta["seed"] == 6
    assert set(episode.arrays) == {"rgbd"}
    np.testing.assert_array_equal(episode.arrays["rgbd"]["depth"], arrays["rgbd"]["depth"])
    assert not ep.stale_temp_dirs(tmp_path)


def test_truncated_npz_names_episode_and_file(tmp_path):
    path = ep.write_episode(tmp_path, 0, 0, {}, _arrays())
    npz = path / "rgbd.npz"
    npz.write_bytes(npz.read_bytes()[: npz.stat().st_size // 2])
    with pytest.raises(ep.CorruptEpisodeError, match=r"000000-0.*rgbd\.npz"):
        ep.load_episode(path)
    with pytest.raises(ep.CorruptEpisodeError, match=r"000000-0.*rgbd\.npz.*truncated"):
        ep.verify_episode(path)


def test_corrupt_bytes_detected_by_verify(tmp_path):
    path = ep.write_episode(tmp_path, 1, 2, {}, _arrays())
    npz = path / "imagery.npz"
    data = bytearray(npz.read_bytes())
    data[len(data) // 3] ^= 0xFF
    npz.write_bytes(bytes(data))
    with pytest.raises(ep.CorruptEpisodeError, match=r"000001-2.*imagery\.npz"):
        ep.verify_episode(path)


def test_missing_meta_named(tmp_path):
    path = ep.write_episode(tmp_path, 1, 2, {}, _arrays())
    (path / "meta.json").unlink()
    with pytest.raises(ep.CorruptEpisodeError, match=r"000001-2.*meta\.json"):
        ep.load_episode(path)


def test_no_pickle_on_write_or_load(tmp_path):
    with pytest.raises(TypeError, match="object"):
        ep.write_episode(tmp_path, 0, 0, {}, {"rgbd": {"x": np.array([{"a": 1}], dtype=object)}})
    assert not ep.list_episodes(tmp_path) and not ep.stale_temp_dirs(tmp_path)
    # An object array planted in a stored file is refused (np.load with allow_pickle=False).
    path = ep.write_episode(tmp_path, 1, 2, {}, _arrays())
    np.savez(path / "rgbd.npz", x=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ep.CorruptEpisodeError, match=r"000001-2.*rgbd\.npz"):
        ep.load_episode(path)


def test_interrupted_write_leaves_no_episode(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = np.savez_compressed

    def failing(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt  # killed between two files
        return real(*args, **kwargs)

    monkeypatch.setattr(np, "savez_compressed", failing)
    with pytest.raises(KeyboardInterrupt):
        ep.write_episode(tmp_path, 0, 0, {}, _arrays())
    assert not ep.list_episodes(tmp_path) and not ep.stale_temp_dirs(tmp_path)


def test_temp_dir_of_dead_process_is_ignored_and_removed(tmp_path):
    import socket

    dead_pid = 2**22 + 12345  # above the default pid_max: no such process
    stale = tmp_path / f".tmp-000000-0-{socket.gethostname()}-{dead_pid}"
    stale.mkdir()
    (stale / "rgbd.npz").write_bytes(b"partial")
    alive = tmp_path / f".tmp-000001-2-{socket.gethostname()}-{os.getppid()}"
    alive.mkdir()
    assert ep.list_episodes(tmp_path) == []
    assert ep.remove_stale_temp_dirs(tmp_path) == [stale]
    assert ep.stale_temp_dirs(tmp_path) == [alive]


WORLD = {"fingerprint": "f" * 16, "format": 2, "modules": {"sim/env.py": "a" * 12}}
COMMAND = "nerf-transporter generate --task block-insertion --regenerate"


def test_dataset_config_mismatch_names_difference(tmp_path):
    config = {
        "task": "block-insertion",
        "imagery": "oracle",
        "pixel_size": 0.0125,
        "grid": [7, 7],
        "world": WORLD,
    }
    ep.ensure_dataset_config(tmp_path, config, COMMAND)
    ep.ensure_dataset_config(tmp_path, dict(config), COMMAND)  # same config: accepted
    with pytest.raises(ep.DatasetConfigMismatchError) as error:
        ep.ensure_dataset_config(tmp_path, {**config, "imagery": "nerf", "grid": [11, 11]}, COMMAND)
    message = str(error.value)
    assert "imagery: stored 'oracle', requested 'nerf'" in message
    assert "grid: stored [7, 7], requested [11, 11]" in message
    assert "pixel_size" not in message and message.endswith(COMMAND)
    assert json.loads((tmp_path / "dataset.json").read_text())["imagery"] == "oracle"


def test_failed_seeds_recorded(tmp_path):
    ep.record_failure(tmp_path, 8, "timeout")
    assert ep.failed_seeds(tmp_path) == {8: "timeout"}


def _place_meta() -> dict:
    return {"action": {"place": {"xyz": [0.5, 0.1, 0.05], "quat_xyzw": [0.0, 0.0, 0.0, 1.0]}}}


def _rewrite_meta(path, change) -> None:
    meta = json.loads((path / "meta.json").read_text())
    change(meta)
    (path / "meta.json").write_text(json.dumps(meta, indent=2))


def test_edited_place_pose_fails_verify_and_load(tmp_path):
    path = ep.write_episode(tmp_path, 3, 6, _place_meta(), _arrays())
    ep.verify_episode(path)
    _rewrite_meta(path, lambda meta: meta["action"]["place"]["xyz"].__setitem__(0, 0.52))
    for check in (ep.verify_episode, ep.load_episode):
        with pytest.raises(
            ep.CorruptEpisodeError, match=r"000003-6: meta\.json does not match"
        ) as e:
            check(path)
        assert f"delete {path}" in str(e.value)


def test_episode_of_format_1_is_refused(tmp_path):
    path = ep.write_episode(tmp_path, 0, 0, {}, _arrays())

    def old_format(meta):
        meta["format"] = 1
        meta["meta_sha256"] = ep.meta_checksum(meta)

    _rewrite_meta(path, old_format)
    with pytest.raises(
        ep.CorruptEpisodeError, match=r"000000-0: format 1, expected 2.*--regenerate"
    ):
        ep.load_episode(path)


def test_losing_the_rename_race_keeps_the_other_writers_episode(tmp_path, monkeypatch):
    """Two processes write the same episode; the one that renames second keeps the first's."""
    other = ep.write_episode(tmp_path / "other", 0, 0, {"writer": "other"}, _arrays())
    real_rename = os.rename

    def rename_after_the_other(source, target):
        real_rename(other, target)  # the other process renames its copy in between
        real_rename(source, target)

    monkeypatch.setattr(os, "rename", rename_after_the_other)
    path = ep.write_episode(tmp_path, 0, 0, {"writer": "me"}, _arrays(1))
    assert ep.load_episode(path).meta["writer"] == "other"
    assert [ref.path for ref in ep.list_episodes(tmp_path)] == [path]
    assert not ep.stale_temp_dirs(tmp_path)


def test_temp_dirs_of_another_host_are_removed_after_a_day(tmp_path):
    old = tmp_path / ".tmp-000000-0-some-other-host-1234"
    recent = tmp_path / ".tmp-000001-2-some-other-host-1234"
    for path in (old, recent):
        path.mkdir()
        (path / "rgbd.npz").write_bytes(b"partial")
    two_days_ago = time.time() - 2 * 24 * 3600
    os.utime(old, (two_days_ago, two_days_ago))
    assert ep.remove_stale_temp_dirs(tmp_path) == [old]
    assert ep.stale_temp_dirs(tmp_path) == [recent]


def test_corrupt_failed_seed_record_is_named(tmp_path):
    ep.record_failure(tmp_path, 8, "timeout")
    (tmp_path / "failed" / "8.json").write_text('{"seed": 8, "rea')
    with pytest.raises(ep.CorruptEpisodeError, match=r"failed/8\.json is corrupt.*delete it"):
        ep.failed_seeds(tmp_path)
