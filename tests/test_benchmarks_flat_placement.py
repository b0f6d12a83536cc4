"""benchmarks/flat_placement.py: its flat actions and aim, its records (merging, resuming) and its
summary, on synthetic records; one tiny real run checks that an execution does not depend on what
ran before it."""

import importlib.util
import json
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from nerf_transporter import geometry as g
from nerf_transporter.sim.tasks.base import MatchTolerance

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
UPRIGHT = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def fp():
    """The script as a module (registered while loading, as a script's module would be)."""
    spec = importlib.util.spec_from_file_location(
        "flat_placement", BENCHMARKS / "flat_placement.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(spec.name, None)


def tilted_scene():
    """A flat block, a pick point 2 cm above its origin and a target tilted 30 deg in pitch."""
    block = (np.array([0.4, 0.2, 0.02]), g.euler_to_quat(0.0, 0.0, 0.3))
    pick = (block[0] + np.array([0.0, 0.0, 0.02]), UPRIGHT)
    target = (np.array([0.5, 0.0, 0.1]), g.euler_to_quat(0.0, math.radians(30), 1.0))
    oracle = {"pick": pick, "place": g.multiply_poses(target, g.invert_pose(block), pick)}
    return block, target, oracle


def test_centred_demonstration_puts_the_origin_flat_above_the_target(fp):
    block, target, oracle = tilted_scene()
    centred = fp.carried_pose(block, fp.centred_demonstration(oracle, block))
    np.testing.assert_allclose(centred[0][:2], target[0][:2], atol=1e-9)
    roll, pitch, yaw = g.quat_to_euler(centred[1])
    assert (roll, pitch) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert yaw == pytest.approx(1.0)
    # through the labels: within a pixel and a rotation bin of that, flat
    height = np.zeros(g.image_shape(g.PIXEL_SIZE), dtype=np.float32)
    action = fp.flat_policy_action(fp.centred_demonstration(oracle, block), height)
    aim = fp.aim(MatchTolerance(0.02), block, action, target)
    assert aim["position_mm"] < 1000 * g.PIXEL_SIZE
    assert aim["yaw_deg"] <= 180 / g.N_ROTATIONS + 1e-6
    assert aim["tilt_deg"] == pytest.approx(30.0, abs=1e-6)  # flat against the tilted target


def test_a_flat_block_carried_from_a_tilted_pick_point_lands_downhill(fp):
    block, target, oracle = tilted_scene()
    flat = {"pick": oracle["pick"], "place": (oracle["place"][0], g.euler_to_quat(0, 0, 0.7))}
    tolerance = MatchTolerance(0.02)
    tilted = fp.aim(tolerance, block, oracle, target)
    assert tilted["position_mm"] == pytest.approx(0.0, abs=1e-6)
    assert tilted["passes"]
    aimed = fp.aim(tolerance, block, flat, target)
    assert aimed["downhill_mm"] == pytest.approx(20 * math.sin(math.radians(30)))
    assert aimed["position_mm"] == pytest.approx(aimed["downhill_mm"])


def record(seed=1, variant="se2", success=True, strict=False, tilt=25.0, **fields):
    """A synthetic record of block-insertion, Normal."""
    return {
        "fingerprint": "f00",
        "task": "block-insertion",
        "setting": "normal",
        "seed": seed,
        "variant": variant,
        "target_tilt_deg": tilt,
        "aim": {"position_mm": 4.0, "downhill_mm": 3.0, "tilt_deg": tilt, "yaw_deg": 1.0},
        "success": success,
        "strict_success": strict,
        "failure": None,
        "release": {"touching": "target", "passes": False, "moved_mm": 30.0, "turned_deg": 20.0},
        "wall_s": 2.0,
        "cpu": "test cpu",
    } | fields


def write_lines(path: Path, records) -> Path:
    path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return path


def test_summary_rates_bands_and_diagnostics(fp):
    records = [
        record(1, success=True, strict=True, tilt=5.0),
        record(3, success=True, strict=False, tilt=25.0),
        record(5, success=False, tilt=27.0, failure="unreachable: place pose", release=None),
        record(1, variant="oracle", tilt=5.0),
        record(1, setting="challenging", tilt=41.0),
    ]
    summary = fp.summarise(records)
    assert list(summary["block-insertion"]) == ["normal", "challenging"]
    se2 = summary["block-insertion"]["normal"]["se2"]
    assert (se2["success"]["successes"], se2["success"]["n"]) == (2, 3)
    assert se2["success"]["ci95"] == pytest.approx(list(fp.wilson_interval(2, 3)))
    assert se2["strict_success"]["successes"] == 1
    assert se2["motion_failures"] == 1
    assert se2["release_touching"] == {"target": 2}
    assert list(se2["tilt_bands"]) == ["0-10", "20-30"]
    assert se2["tilt_bands"]["20-30"]["success"]["n"] == 2
    assert se2["moved_after_release_mm"]["failures"] == {}
    assert se2["aim_position_mm"]["failures"]["median"] == 4.0

    text = fp.summary_text(records, markdown=True)
    assert "5 executions, world fingerprint f00" in text
    assert "| block-insertion | normal | `se2` | 2/3 = 67% (21-94) | 1/3 = 33% (6-79) | 1 |" in text
    assert "| block-insertion | normal | 20-30 | - | - | 1/2 = 50% (9-91) | 0/2 = 0% (0-66) |" in (
        text
    )
    assert "| --- |" in text
    plain = fp.summary_text(records, markdown=False)
    assert "|" not in plain and "== Success" in plain


def test_records_of_several_files_merge_and_other_worlds_are_refused(fp, tmp_path, capsys):
    first = write_lines(tmp_path / "a.jsonl", [record(1), record(3)])
    second = write_lines(tmp_path / "b.jsonl", [record(3), record(5)])
    with second.open("a") as stream:
        stream.write('{"fingerprint": "f00", "ta')  # a write cut short
    merged = fp.load_records([first, second])
    assert sorted(r["seed"] for r in merged) == [1, 3, 5]
    assert "incomplete last line" in capsys.readouterr().err

    other = write_lines(tmp_path / "c.jsonl", [record(1, fingerprint="bad", success=False)])
    with pytest.raises(SystemExit, match="refusing to merge records of different worlds"):
        fp.load_records([first, other])
    disagreeing = write_lines(tmp_path / "d.jsonl", [record(1, success=False)])
    with pytest.raises(SystemExit, match="disagree"):
        fp.load_records([first, disagreeing])


def test_an_out_file_of_another_world_is_refused_and_a_cut_line_removed(fp, tmp_path):
    out = write_lines(tmp_path / "out.jsonl", [record(1), record(3)])
    with out.open("a") as stream:
        stream.write('{"fingerprint": "f0')
    assert fp.recorded_keys(out, "f00") == {
        ("block-insertion", "normal", 1, "se2"),
        ("block-insertion", "normal", 3, "se2"),
    }
    assert out.read_text().endswith("}\n")
    with pytest.raises(SystemExit, match="holds records of world fingerprint f00"):
        fp.recorded_keys(out, "f01")


@pytest.fixture
def executed(fp, monkeypatch):
    """The executions `measure` runs, simulated by synthetic records (seed 99's first raises)."""
    executions = []

    def fake_seed(env, seed, variants):
        for variant in variants:
            if seed == 99:
                raise RuntimeError("no reachable target pose")
            executions.append((env.task, seed, variant))
            added = ("fingerprint", "task", "setting", "seed", "cpu")  # by `measure`
            yield {k: v for k, v in record(seed, variant).items() if k not in added}

    monkeypatch.setattr(fp, "world_fingerprint", lambda: "f00")
    monkeypatch.setattr(fp, "measure_seed", fake_seed)
    monkeypatch.setattr(
        fp, "make_env", lambda task, setting, rigs: SimpleNamespace(task=task, close=lambda: None)
    )
    return executions


def test_a_rerun_executes_only_what_its_out_file_lacks(fp, executed, tmp_path, capsys):
    out = write_lines(tmp_path / "out.jsonl", [record(1, "oracle"), record(3, "se2")])
    argv = ["--tasks", "block-insertion", "--settings", "normal", "--episodes", "2"]
    assert fp.main([*argv, "--variants", "oracle", "se2", "--out", str(out)]) == 0
    assert executed == [("block-insertion", 1, "se2"), ("block-insertion", 3, "oracle")]
    assert len(out.read_text().splitlines()) == 4
    assert "| " not in capsys.readouterr().out  # plain text without --markdown

    executed.clear()
    assert fp.main([*argv, "--variants", "oracle", "se2", "--out", str(out), "--markdown"]) == 0
    assert executed == []
    assert "2/2 = 100%" in capsys.readouterr().out


def test_a_seed_that_raises_is_reported_and_the_others_recorded(fp, executed, capsys):
    records, errors = fp.measure(["block-insertion"], ["normal"], [99, 1], ["se2"], set(), None)
    assert errors == 1
    assert [r["seed"] for r in records] == [1]
    assert "block-insertion normal seed 99: RuntimeError: no reachable target pose" in (
        capsys.readouterr().err
    )


def test_an_execution_does_not_depend_on_what_ran_before_it(fp, tmp_path, capsys):
    """Real simulation, one seed: `se2_centred` after `se2` (the heightmap rendered for `se2`)
    and alone after a resume (rendered for itself) give the same record."""
    out = tmp_path / "out.jsonl"
    argv = ["--tasks", "block-insertion", "--settings", "normal", "--episodes", "1"]
    argv += ["--variants", "se2", "se2_centred", "--out", str(out)]
    assert fp.main(argv) == 0
    first = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["variant"] for r in first] == ["se2", "se2_centred"]
    write_lines(out, first[:1])
    assert fp.main(argv) == 0
    second = [json.loads(line) for line in out.read_text().splitlines()]
    assert second[0] == first[0]
    assert {k: v for k, v in second[1].items() if k != "wall_s"} == {
        k: v for k, v in first[1].items() if k != "wall_s"
    }
    assert "2 executions" in capsys.readouterr().out
