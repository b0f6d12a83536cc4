"""Generation logic on a small deterministic stand-in for the simulator (fast), plus one run on the
real simulator."""

import json
import socket

import numpy as np
import pytest

from nerf_transporter import geometry as g
from nerf_transporter.data import episode as ep
from nerf_transporter.data import generate as gen
from nerf_transporter.data import info
from nerf_transporter.imagery import psnr
from nerf_transporter.splits import split_seed
from tests.helpers.fake_sim import PIXEL, FakeEnv, changed_world


def oracle_config(**changes) -> gen.GenerationConfig:
    return gen.GenerationConfig(
        **{
            "task": "block-insertion",
            "imagery": "oracle",
            "pixel_size": PIXEL,
            "nerf_views": 2,
            **changes,
        }
    )


def successful_indices(count: int) -> list[int]:
    return [k for k in range(2 * count) if k % 4 != 1][:count]


def test_generate_keeps_successes_and_reruns_add_nothing(fake_world, tmp_path):
    config = oracle_config()
    dataset = gen.generate_dataset(config, 3, tmp_path, progress=False)
    refs = ep.list_episodes(dataset)
    assert [r.index for r in refs] == successful_indices(3)
    assert [r.seed for r in refs] == [split_seed("train", k) for k in successful_indices(3)]
    assert set(ep.failed_seeds(dataset)) == {split_seed("train", 1)}
    assert "position 3.0 cm" in ep.failed_seeds(dataset)[2]
    stamps = {r.path.name: r.path.stat().st_mtime_ns for r in refs}
    gen.generate_dataset(config, 3, tmp_path, progress=False)
    assert {r.path.name: r.path.stat().st_mtime_ns for r in ep.list_episodes(dataset)} == stamps
    gen.generate_dataset(config, 5, tmp_path, progress=False)  # larger --episodes continues
    assert [r.index for r in ep.list_episodes(dataset)] == successful_indices(5)
    episode = ep.load_episode(refs[0].path)
    assert episode.arrays["imagery"]["colour"].shape == (49, *g.image_shape(PIXEL), 3)
    assert episode.arrays["imagery"]["height"].dtype == np.float16
    assert episode.arrays["nerf_views"]["rgb"].shape == (2, 6, 8, 3)
    assert json.loads((dataset / "dataset.json").read_text())["pixel_size"] == PIXEL


def test_an_episode_records_the_strict_check_of_its_oracle_run(fake_world, tmp_path, monkeypatch):
    class JudgedEnv(FakeEnv):
        def step(self, action):
            *outcome, step_info = super().step(action)
            return *outcome, step_info | {"strict_success": False}  # the reward won, not the strict

    monkeypatch.setattr(gen, "_env", lambda config: JudgedEnv())
    dataset = gen.generate_dataset(oracle_config(), 1, tmp_path, progress=False)
    (ref,) = ep.list_episodes(dataset)
    meta = ep.read_meta(ref.path)
    assert (meta["success"], meta["strict_success"]) == (True, False)


def test_killed_generation_resumes_without_duplicates(fake_world, tmp_path, monkeypatch):
    config = oracle_config()
    real_write = ep.write_episode
    calls = {"n": 0}

    def dying_write(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:  # dies in the middle of the second episode's files
            real_savez = np.savez_compressed
            monkeypatch.setattr(
                np, "savez_compressed", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt())
            )
            try:
                return real_write(*args, **kwargs)
            finally:
                monkeypatch.setattr(np, "savez_compressed", real_savez)
        return real_write(*args, **kwargs)

    monkeypatch.setattr(ep, "write_episode", dying_write)
    with pytest.raises(KeyboardInterrupt):
        gen.generate_dataset(config, 4, tmp_path, progress=False)
    dataset = tmp_path / config.dataset_name()
    assert len(ep.list_episodes(dataset)) == 1
    # a hard kill (SIGKILL) leaves its temporary directory behind
    dead = dataset / f".tmp-{ep.episode_dirname(2, 4)}-{socket.gethostname()}-{2**22 + 4321}"
    dead.mkdir()
    (dead / "imagery.npz").write_bytes(b"half")
    monkeypatch.setattr(ep, "write_episode", real_write)
    gen.generate_dataset(config, 4, tmp_path, progress=False)
    refs = ep.list_episodes(dataset)
    assert [r.index for r in refs] == successful_indices(4)
    assert len({r.seed for r in refs}) == 4 and not ep.stale_temp_dirs(dataset)
    for ref in refs:
        ep.verify_episode(ref.path)


def test_shards_together_make_the_dataset(fake_world, tmp_path):
    config = oracle_config()
    for shard in range(3):
        gen.generate_dataset(config, 5, tmp_path, shard=(shard, 3), progress=False)
    refs = ep.list_episodes(tmp_path / config.dataset_name())
    assert len(refs) == 5 and len({r.seed for r in refs}) == 5
    assert gen.shard_target(5, (0, 3)) == 2 and gen.shard_target(5, (2, 3)) == 1
    with pytest.raises(ValueError, match="i/n"):
        gen.parse_shard("3")


def test_broken_oracle_stops_with_a_reason(fake_world, tmp_path):
    with pytest.raises(
        RuntimeError, match=r"3 oracle rollouts failed in a row \(last: seed .*position 3.0 cm"
    ):
        gen.generate_dataset(
            oracle_config(), 2, tmp_path, shard=(1, 4), progress=False, max_failures_in_a_row=3
        )


def test_config_mismatch_refused_with_difference(fake_world, tmp_path, capsys):
    gen.generate_dataset(oracle_config(), 1, tmp_path, progress=False)
    config = oracle_config(nerf_views=5)
    with pytest.raises(
        ep.DatasetConfigMismatchError, match=r"cameras.nerf.views: stored 2, requested 5"
    ):
        gen.generate_dataset(config, 1, tmp_path, progress=False)
    code = gen.main(cli_args(tmp_path, "--nerf-views", "5"))
    assert code == 2 and "cameras.nerf.views: stored 2, requested 5" in capsys.readouterr().err


def test_dataset_info_and_verify(fake_world, tmp_path, capsys):
    dataset = gen.generate_dataset(oracle_config(), 2, tmp_path, progress=False)
    assert info.main([str(dataset), "--verify", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (
        summary["episodes"] == 2 and summary["verified"] is True and summary["imagery"] == "oracle"
    )
    assert summary["seeds"] == [0, 4]
    victim = ep.list_episodes(dataset)[1].path / "rgbd.npz"
    victim.write_bytes(victim.read_bytes()[:100])
    assert info.main([str(dataset), "--verify", "--json"]) == 1
    output = capsys.readouterr().out
    summary = json.loads(output.strip().splitlines()[-1])
    assert summary["verified"] is False and "000002-4: rgbd.npz" in output


def test_command_reproduces_config():
    config = oracle_config(nerf_views=0)
    command = config.command(7, "data")
    assert command == (
        "nerf-transporter generate --task block-insertion --setting normal --split train --episodes 7 "
        "--imagery oracle --data-dir data --pixel-size 0.0125 --nerf-views 0"
    )
    args = gen.build_parser().parse_args(command.split()[2:])
    assert (args.pixel_size, args.nerf_views, args.imagery) == (PIXEL, 0, "oracle")


def test_real_simulator_episode(tmp_path):
    """One real oracle episode with ground-truth imagery: stored labels match the stored views."""
    pytest.importorskip("pybullet")
    from nerf_transporter.data.labels import mira_labels

    config = oracle_config(nerf_views=0)
    dataset = gen.generate_dataset(config, 1, tmp_path, progress=False)
    (ref,) = ep.list_episodes(dataset)
    ep.verify_episode(ref.path)
    episode = ep.load_episode(ref.path)
    action = gen.action_from_meta(episode.meta)
    labels = mira_labels(action, config.grid, PIXEL)
    imagery = episode.arrays["imagery"]
    assert int(imagery["place_view"]) == labels.place_view
    # the pick pixel lies on the object: higher than the table in the top-down view
    top = g.top_down_view_index(config.grid)
    assert float(imagery["height"][top][labels.pick_pixel]) > 0.01
    assert episode.meta["success"] is True and set(episode.meta["timings_s"]) >= {
        "capture",
        "rollout",
    }
    # the oracle solves the first training seed: it is stored, no seed is recorded as failed
    assert (ref.index, ref.seed) == (0, 0)
    assert ep.failed_seeds(dataset) == {} and not (dataset / ep.FAILED_DIR).exists()


@pytest.mark.slow
def test_real_nerf_imagery_episode(tmp_path):
    """A NeRF-imagery episode (tiny fit): imagery, ground truth of two views and quality stored."""
    config = gen.GenerationConfig(
        "block-insertion",
        imagery="nerf",
        pixel_size=PIXEL,
        nerf_views=6,
        nerf_image_size=(60, 80),
        imagery_options={"iterations": 100, "batch_rays": 512},
    )
    dataset = gen.generate_dataset(config, 1, tmp_path, progress=False)
    (ref,) = ep.list_episodes(dataset)
    episode = ep.load_episode(ref.path)
    imagery = episode.arrays["imagery"]
    assert imagery["colour"].shape == (49, *g.image_shape(PIXEL), 3)
    assert set(imagery["truth_view_ids"].tolist()) <= {24, int(imagery["place_view"])}
    assert episode.arrays["nerf_views"]["rgb"].shape == (6, 60, 80, 3)
    # Measured with this config (seed 0, one thread; the default imagery, whose field starts at
    # the table's colour, so that 30 iterations leave it at the mean colour's 24.7 dB): PSNR
    # 25.54 dB, height error 1.25 mm (1.13 mm on objects). On the same views the mean-colour image
    # scores 24.70 dB (uniform grey 12.41), a flat table at z = 0 is 75.5 mm off (146.5 mm on
    # objects). Thresholds: PSNR above the mean-colour image's by half the measured lead (0.4 of
    # 0.84 dB), heights within 5 mm (about four times the measured errors, a fifteenth of the flat
    # table's).
    quality = episode.meta["imagery"]["quality"]
    truth_colour = imagery["truth_colour"]
    mean_colour = np.broadcast_to(
        truth_colour.reshape(-1, 3).mean(0).round().astype(np.uint8), truth_colour.shape
    )
    assert quality["psnr_db"] > psnr(mean_colour, truth_colour) + 0.4, quality
    assert quality["height_mae_mm"] < 5.0 and quality["object_height_mae_mm"] < 5.0, quality
    assert (
        json.loads((dataset / "dataset.json").read_text())["imagery"]["config"]["iterations"] == 100
    )


def cli_args(data_dir, *changes: str) -> list[str]:
    """`nerf-transporter generate` arguments of oracle_config() (later options override)."""
    return [
        "--task",
        "block-insertion",
        "--imagery",
        "oracle",
        "--episodes",
        "1",
        "--pixel-size",
        str(PIXEL),
        "--nerf-views",
        "2",
        "--data-dir",
        str(data_dir),
        "--no-progress",
        *changes,
    ]


def test_data_of_another_world_is_refused_until_regenerated(
    fake_world, tmp_path, capsys, monkeypatch
):
    config = oracle_config()
    dataset = gen.generate_dataset(config, 2, tmp_path, progress=False)
    assert json.loads((dataset / "dataset.json").read_text())["world"] == gen.fingerprint.world()
    (ref, _) = ep.list_episodes(dataset)
    assert ep.read_meta(ref.path)["generation"] == json.loads(
        (dataset / "dataset.json").read_text()
    )
    other_world = changed_world(gen.fingerprint.world())
    monkeypatch.setattr(gen.fingerprint, "world", lambda: other_world)
    command = config.command(3, tmp_path, regenerate=True)
    with pytest.raises(ep.WorldMismatchError) as error:
        gen.generate_dataset(config, 3, tmp_path, progress=False)
    assert "the physics and tasks (physics) changed" in str(error.value)
    assert str(error.value).endswith(command)
    (dataset / "dataset.json").unlink()  # the episodes' own records refuse them too
    with pytest.raises(ep.WorldMismatchError, match=r"000000-0\).*\n  the physics and tasks"):
        gen.generate_dataset(config, 3, tmp_path, progress=False)
    assert len(ep.list_episodes(dataset)) == 2 and not (dataset / "dataset.json").exists()
    assert gen.main(cli_args(tmp_path, "--episodes", "3")) == 2
    assert "(physics) changed" in capsys.readouterr().err
    assert gen.main(cli_args(tmp_path, "--episodes", "3", "--regenerate")) == 0
    assert json.loads((dataset / "dataset.json").read_text())["world"] == other_world
    refs = ep.list_episodes(dataset)
    assert len(refs) == 3 and ep.read_meta(refs[0].path)["generation"]["world"] == other_world


def test_dataset_without_a_recorded_world_is_refused(fake_world, tmp_path):
    config = oracle_config()
    dataset = gen.generate_dataset(config, 1, tmp_path, progress=False)
    stored = json.loads((dataset / "dataset.json").read_text())
    del stored["world"]  # as written before datasets recorded their world
    (dataset / "dataset.json").write_text(json.dumps(stored))
    with pytest.raises(
        ep.WorldMismatchError,
        match=r"(?s)no world is recorded.*\n  nerf-transporter generate .*--regenerate$",
    ):
        gen.generate_dataset(config, 1, tmp_path, progress=False)


def test_regenerate_deletes_only_its_own_dataset(fake_world, tmp_path):
    kept = gen.generate_dataset(oracle_config(pixel_size=0.025), 1, tmp_path, progress=False)
    dataset = gen.generate_dataset(oracle_config(), 3, tmp_path, progress=False)
    assert ep.failed_seeds(dataset)
    before = {ref.path.name: ref.path.stat().st_ino for ref in ep.list_episodes(kept)}
    gen.generate_dataset(oracle_config(), 1, tmp_path, progress=False, regenerate=True)
    assert [ref.index for ref in ep.list_episodes(dataset)] == [0] and not ep.failed_seeds(dataset)
    assert {ref.path.name: ref.path.stat().st_ino for ref in ep.list_episodes(kept)} == before


def test_other_options_cannot_slip_in_after_dataset_json_is_deleted(fake_world, tmp_path):
    dataset = gen.generate_dataset(oracle_config(), 1, tmp_path, progress=False)
    (dataset / "dataset.json").unlink()
    other = oracle_config(pixel_size=PIXEL + 1e-10)  # the same folder name (-px0.0125)
    assert other.dataset_name() == dataset.name
    with pytest.raises(
        ep.DatasetConfigMismatchError, match=r"000000-0\).*\n  pixel_size: stored 0.0125, requested"
    ):
        gen.generate_dataset(other, 2, tmp_path, progress=False)
    assert len(ep.list_episodes(dataset)) == 1 and not (dataset / "dataset.json").exists()
    gen.generate_dataset(oracle_config(), 2, tmp_path, progress=False)  # the episodes' options
    assert json.loads((dataset / "dataset.json").read_text())["pixel_size"] == PIXEL


def test_edited_label_fails_dataset_info_verify(fake_world, tmp_path, capsys):
    dataset = gen.generate_dataset(oracle_config(), 1, tmp_path, progress=False)
    meta_path = ep.list_episodes(dataset)[0].path / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["action"]["place"]["xyz"][1] += 0.01
    meta_path.write_text(json.dumps(meta))
    assert info.main([str(dataset), "--verify"]) == 1
    assert "000000-0: meta.json does not match its checksum" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        (("--episodes", "0"), "--episodes must be >= 1, got 0"),
        (("--episodes", "-3"), "--episodes must be >= 1, got -3"),
        (("--pixel-size", "0"), "--pixel-size must be > 0"),
        (("--pixel-size", "-0.0125"), "--pixel-size must be > 0"),
        (("--pixel-size", "nan"), "--pixel-size must be > 0"),
        (("--nerf-views", "-1"), "--nerf-views must be >= 0"),
        (("--task", "nope"), "unknown task 'nope'; valid tasks: block-insertion"),
        (("--setting", "weird"), "unknown setting 'weird'; valid settings: normal"),
    ],
)
def test_bad_arguments_are_refused_before_anything_is_written(
    fake_world, tmp_path, capsys, changes, named
):
    assert gen.main(cli_args(tmp_path / "data", *changes)) == 2
    error = capsys.readouterr().err
    assert error.startswith(f"nerf-transporter generate: {named}") and error.count("\n") == 1
    assert not (tmp_path / "data").exists()


@pytest.mark.parametrize("content", [b"\x89PNG\r\n\x1a\n\x00\xff", b"[1, 2]", b'"oracle"'])
def test_unreadable_dataset_json_is_named(fake_world, tmp_path, capsys, content):
    dataset = tmp_path / oracle_config().dataset_name()
    dataset.mkdir()
    (dataset / "dataset.json").write_bytes(content)
    assert gen.main(cli_args(tmp_path)) == 2
    error = capsys.readouterr().err
    assert error.startswith(f"nerf-transporter generate: {dataset / 'dataset.json'} is not a")
    assert [p.name for p in dataset.iterdir()] == ["dataset.json"]


def test_corrupt_failed_record_is_named_and_nothing_written(fake_world, tmp_path, capsys):
    dataset = gen.generate_dataset(oracle_config(), 2, tmp_path, progress=False)
    record = dataset / "failed" / f"{split_seed('train', 1)}.json"
    record.write_bytes(b"\x00\x01")
    before = sorted(p.relative_to(dataset) for p in dataset.rglob("*"))
    assert gen.main(cli_args(tmp_path, "--episodes", "4")) == 2
    error = capsys.readouterr().err
    assert error.startswith(f"nerf-transporter generate: failed-seed record {record} is corrupt")
    assert "delete it" in error
    assert sorted(p.relative_to(dataset) for p in dataset.rglob("*")) == before
