"""The world fingerprint follows what decides an episode, component by component, not the code's
shape; the cells, datasets and policies of the source-hash scheme's world stay this world's."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from nerf_transporter.cli import main as cli_main
from nerf_transporter.data import episode as ep
from nerf_transporter.experiments import pretrained
from nerf_transporter.experiments.cells import CellFileError, load_record
from nerf_transporter.pretrained import PRETRAINED_DIR
from nerf_transporter.sim import fingerprint, trace

BLOCK = "sim/tasks/block_insertion.py"
RESULTS = Path(__file__).resolve().parents[2] / "results"
SOURCE_HASH_WORLD = "2b2aee17dfd72f31"  # the fingerprint the cells were measured under
ARCHIVED_WORLD = "cebd2134fda05fac"  # results/archive/world-<it>: an earlier world's cells


def _copy_package(tmp_path: Path) -> Path:
    root = tmp_path / "nerf_transporter"
    shutil.copytree(fingerprint.PACKAGE_ROOT, root, ignore=shutil.ignore_patterns("__pycache__"))
    assert fingerprint.world_description(root) == fingerprint.world()  # the installed package
    return root


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_an_unused_function_in_the_environment_changes_no_fingerprint(tmp_path):
    root = _copy_package(tmp_path)
    env = root / "sim" / "env.py"
    env.write_text(
        env.read_text() + '\n\ndef unused_helper(speed: float = 2.0) -> float:\n    """Unused."""\n'
        "    scale = 3.0\n    return scale * speed\n"
    )
    assert fingerprint.world_description(root) == fingerprint.world()


def test_an_edited_comment_changes_nothing(tmp_path):
    root = _copy_package(tmp_path)
    _edit(
        root / BLOCK,
        "# m between a centred block and each wall",
        "# metres from a centred block to each wall",
    )
    assert fingerprint.world_description(root) == fingerprint.world()


def test_a_changed_clearance_changes_the_world_in_physics_alone(tmp_path):
    root = _copy_package(tmp_path)
    _edit(root / BLOCK, "CLEARANCE = 0.009", "CLEARANCE = 0.012")
    old, new = fingerprint.world(), fingerprint.world_description(root)
    assert new["fingerprint"] != old["fingerprint"]
    assert [
        name for name in old["components"] if new["components"][name] != old["components"][name]
    ] == ["physics"]
    assert fingerprint.world_changes(old, new) == ["the physics and tasks (physics) changed"]


def test_a_changed_nerf_rig_changes_the_nerf_rig_alone(tmp_path):
    root = _copy_package(tmp_path)
    _edit(root / "sim" / "cameras.py", "NERF_RADIUS = 1.05", "NERF_RADIUS = 1.1")
    old, new = fingerprint.world(), fingerprint.world_description(root)
    assert fingerprint.world_changes(old, new) == ["the NeRF rig (nerf) changed"]


def test_a_changed_trace_changes_its_component(tmp_path):
    root = _copy_package(tmp_path)
    path = root / "sim" / "world_trace.json"
    trace = json.loads(path.read_text())
    trace["renders"]["rgbd"][0][0] += 0.01
    path.write_text(json.dumps(trace))
    assert fingerprint.world_changes(fingerprint.world(), fingerprint.world_description(root)) == [
        "the RGB-D rig (rgbd) changed"
    ]


def test_the_world_is_recorded_with_its_components():
    world = fingerprint.world()
    recorded = fingerprint.known_worlds()[world["fingerprint"]]
    assert recorded == {"format": world["format"], "components": world["components"]}


def _moved_by_float_noise(committed: dict) -> dict:
    """The committed trace with one settled number moved as an episode's contacts amplify the last
    bits of its arithmetic (3 mm)."""
    moved = json.loads(json.dumps(committed))
    moved["episodes"]["stacking-kits/challenging"]["settled"][4][0] += 0.003
    return moved


def test_a_trace_recorded_as_float_noise_keeps_the_world_and_its_components(tmp_path):
    root = _copy_package(tmp_path)
    path = root / "sim" / "world_trace.json"
    path.write_text(json.dumps(_moved_by_float_noise(fingerprint.committed_trace())))
    moved = fingerprint.world_description(root)
    assert fingerprint.world_changes(fingerprint.world(), moved) == [
        "the physics and tasks (physics) changed"
    ]
    played = fingerprint.component_digests(root)["physics"]
    recorded = fingerprint.world()["components"]["physics"]
    with pytest.raises(ValueError, match="only with the reason"):
        fingerprint.record_float_noise("physics", played, recorded, " ", root / "sim/worlds.json")
    fingerprint.record_float_noise(
        "physics", played, recorded, "summed in another order", root / "sim/worlds.json"
    )
    assert fingerprint.world_description(root) == fingerprint.world()
    assert fingerprint.float_noise_equals(root)["physics"][played] == recorded


def test_same_world_refuses_a_trace_that_differs_beyond_numbers(monkeypatch, capsys):
    """Nothing is written: an asset or an outcome that changed is another world."""
    committed = fingerprint.committed_trace()
    trace_text, worlds_text = (
        path.read_text() for path in (fingerprint.TRACE_FILE, fingerprint.WORLDS_FILE)
    )
    rebuilt = _moved_by_float_noise(committed)
    rebuilt["episodes"]["stacking-kits/challenging"]["outcome"]["success"] = False
    monkeypatch.setattr(trace, "world_trace", lambda: rebuilt)
    assert trace.main(["--write", "--same-world", "summed in another order"]) == 1
    assert "that is another world, written without --same-world" in capsys.readouterr().err
    assert fingerprint.TRACE_FILE.read_text() == trace_text
    assert fingerprint.WORLDS_FILE.read_text() == worlds_text
    with pytest.raises(SystemExit):
        trace.main(["--same-world", "summed in another order"])
    assert "give --write too" in capsys.readouterr().err


def test_the_source_hash_worlds_cells_datasets_and_policies_are_this_worlds(tmp_path):
    """The trace was written in the world the source-hash scheme named 2b2aee17dfd72f31; that
    world keeps its name, so what was made in it stays valid without being rewritten."""
    assert fingerprint.world_fingerprint() == SOURCE_HASH_WORLD
    cells = [path for path in RESULTS.rglob("*.json") if "archive" not in path.parts]
    assert len(cells) >= 54
    for path in cells:
        assert load_record(path)["world"] == SOURCE_HASH_WORLD
    manifest = json.loads((PRETRAINED_DIR / "manifest.json").read_text())
    assert {entry["test"]["world"] for entry in manifest["policies"]} == {SOURCE_HASH_WORLD}
    # a dataset's description written by the source-hash scheme (module digests, no components)
    stored = {"fingerprint": SOURCE_HASH_WORLD, "format": 2, "modules": {"sim/env.py": "c111abf"}}
    assert fingerprint.world_changes(stored, fingerprint.world()) == []
    description = {"task": "hanging-disks", "world": fingerprint.world()}
    (tmp_path / "dataset.json").write_text(json.dumps({**description, "world": stored}))
    assert ep.check_dataset_config(tmp_path, description, "regenerate")  # accepted, exists
    unknown = {**stored, "fingerprint": "f" * 16}
    assert fingerprint.world_changes(unknown, fingerprint.world()) == [
        f"world {'f' * 16} is unknown to this package (not in sim/worlds.json)"
    ]


def test_the_archived_world_is_another_world():
    assert not fingerprint.same_world(ARCHIVED_WORLD, fingerprint.world_fingerprint())
    archived = sorted((RESULTS / "archive" / f"world-{ARCHIVED_WORLD}").rglob("*.json"))
    assert archived
    assert load_record(archived[0])["world"] == ARCHIVED_WORLD  # in its own archive
    with pytest.raises(CellFileError, match=f"measured in world {ARCHIVED_WORLD}"):
        load_record(archived[0], world=fingerprint.world_fingerprint())


def _world_with_a_new_nerf_rig(monkeypatch) -> str:
    world = fingerprint.world()
    changed = {**world, "components": {**world["components"], "nerf": "0" * 16}}
    changed["fingerprint"] = "1" * 16
    monkeypatch.setattr(fingerprint, "_CACHED", changed)
    return changed["fingerprint"]


def test_a_new_nerf_rig_refuses_the_nerf_cells_and_keeps_the_others(monkeypatch, tmp_path):
    new_world = _world_with_a_new_nerf_rig(monkeypatch)
    cells = {path.stem: path for path in (RESULTS / "block-insertion").glob("*.json")}
    for kept in ("transporter_se2", "form2fit", "gt_state_mlp", "mira-oracle"):
        assert load_record(cells[kept], world=new_world)["world"] == SOURCE_HASH_WORLD
    with pytest.raises(CellFileError, match=f"measured in world {SOURCE_HASH_WORLD}"):
        load_record(cells["mira"], world=new_world)
    # the shipped policies alike: those that read NeRF imagery are from another world now
    manifest = json.loads((PRETRAINED_DIR / "manifest.json").read_text())["policies"]
    for entry in manifest:
        if entry["imagery"] == "nerf":
            with pytest.raises(pretrained.ForeignWorldError, match=entry["file"]):
                pretrained.check_world(entry)
        else:
            pretrained.check_world(entry)
    # a dataset holds the NeRF rig's captures: it is refused, naming the component
    description = {"task": "block-insertion", "world": json.loads(json.dumps(fingerprint.world()))}
    stored = {**description, "world": {"fingerprint": SOURCE_HASH_WORLD, "format": 2}}
    (tmp_path / "dataset.json").write_text(json.dumps(stored))
    with pytest.raises(ep.WorldMismatchError, match=r"the NeRF rig \(nerf\) changed"):
        ep.check_dataset_config(tmp_path, description, "regenerate")


def test_the_world_command_prints_every_component(capsys):
    assert cli_main(["world", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == fingerprint.world()
    assert cli_main(["world"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"world {fingerprint.world_fingerprint()} ")
    for name, digest in fingerprint.world()["components"].items():
        assert f"{fingerprint.COMPONENTS[name]}" in out and f"{name}" in out and digest in out


def test_the_fingerprint_is_computed_without_the_simulator():
    """A training machine without PyBullet computes the same fingerprint."""
    code = (
        "import sys; sys.modules['pybullet'] = sys.modules['pybullet_utils'] = None; "
        "from nerf_transporter.sim.fingerprint import world_fingerprint; print(world_fingerprint())"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    result = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == fingerprint.world_fingerprint()
