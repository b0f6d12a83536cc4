"""Pretrained policies: export a trained checkpoint, ship it, `nerf-transporter try` it."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from nerf_transporter import geometry as g
from nerf_transporter.atomic import write_json
from nerf_transporter.cli import main as cli_main
from nerf_transporter.data.episode import file_sha256
from nerf_transporter.evaluation.rollout import EvaluationSpec, Evaluator
from nerf_transporter.evaluation.testing import results_directory, results_record
from nerf_transporter.experiments import pretrained as pretrained_module
from nerf_transporter.experiments.checkpoints import load_checkpoint
from nerf_transporter.experiments.pretrained import (
    ForeignWorldError,
    check_world,
    export_pretrained,
    load_manifest,
    policy_file_name,
    shipped_table,
    try_policy,
)
from nerf_transporter.pretrained import PRETRAINED_DIR
from nerf_transporter.sim.fingerprint import world_fingerprint
from tests.helpers.state_run import trained_state_mlp


def trained_run(tmp_path: Path) -> Path:
    """A 2-step gt_state_mlp run on block-insertion: its checkpoint, beside the run's config."""
    run = tmp_path / "logs" / "block-insertion" / "gt_state_mlp" / "version_0"
    checkpoint = run / "checkpoints" / "step2.ckpt"
    trained_state_mlp(tmp_path).save_checkpoint(checkpoint)
    config = {
        "trainer": {
            "max_steps": 2,
            "callbacks": [
                {
                    "class_path": "nerf_transporter.evaluation.callback.SuccessRateCallback",
                    "init_args": {"episodes": 3},
                }
            ],
        }
    }
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    return checkpoint


def results_of(checkpoint: Path, seeds: list[int]) -> Path:
    """The results file `lightning test` writes for `checkpoint` on `seeds`."""
    model, datamodule = load_checkpoint(checkpoint, torch.device("cpu"))
    spec = EvaluationSpec.from_datamodule(datamodule, split="test", cache_dir=None)
    with Evaluator(spec) as evaluator:
        results = evaluator.run(model, seeds)
    record = results_record(
        [result.to_json() for result in results],
        method=model,
        spec=spec,
        trained_setting=datamodule.setting,
        split="test",
        checkpoint=str(checkpoint),
        global_step=2,
        wall_s=1.0,
    )
    return write_json(checkpoint.parent / f"results-{checkpoint.stem}.json", record)


def test_export_keeps_weights_and_provenance_and_try_runs_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    checkpoint = trained_run(tmp_path)
    results = results_of(checkpoint, [1])
    folder = tmp_path / "pretrained"
    entry = export_pretrained(checkpoint, results, folder, config="tiny.yaml", commit="abc1234")

    shipped = folder / "block-insertion-gt_state_mlp.ckpt"
    state = torch.load(shipped, map_location="cpu", weights_only=True)
    assert "optimizer_states" not in state and "loops" not in state
    original = torch.load(checkpoint, map_location="cpu", weights_only=True)
    for key, value in original["state_dict"].items():
        assert torch.equal(state["state_dict"][key], value)
    assert shipped.stat().st_size < checkpoint.stat().st_size
    assert state["provenance"]["commit"] == "abc1234"
    assert state["provenance"]["trained_steps"] == 2
    assert state["provenance"]["validation"]["episodes"] == 3
    assert state["provenance"]["test"]["seeds"] == [1]
    assert load_manifest(folder) == [entry]
    assert entry["sha256"] == file_sha256(shipped)
    assert entry["test"]["world"] == world_fingerprint()  # trained and tested in this world

    record = try_policy(
        "block-insertion", "gt_state_mlp", 1, tmp_path / "videos", folder=folder, cache_dir=None
    )
    # the shipped policy acts exactly as the checkpoint it came from
    expected = json.loads(results.read_text())["episode_results"][0]
    assert record["episode_results"][0]["success"] == expected["success"]
    assert record["episode_results"][0]["action"] == expected["action"]
    assert sorted(p.name for p in (tmp_path / "videos").glob("*.mp4")) == [
        "block-insertion-normal-seed1-gt_state_mlp.mp4"
    ]
    # once the world has changed, the same policy is refused by name
    monkeypatch.setattr(pretrained_module, "world_fingerprint", lambda: "f" * 16)
    with pytest.raises(ForeignWorldError, match="block-insertion/gt_state_mlp"):
        try_policy("block-insertion", "gt_state_mlp", 1, None, folder=folder, cache_dir=None)


def test_export_refuses_the_results_of_another_checkpoint(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    checkpoint = trained_run(tmp_path)
    results = results_of(checkpoint, [1])
    other = checkpoint.with_name("step9.ckpt")
    state = torch.load(checkpoint, map_location="cpu", weights_only=True)
    for tensor in state["state_dict"].values():
        tensor.add_(1.0)
    torch.save(state, other)
    with pytest.raises(ValueError, match="tests another checkpoint than .*step9.ckpt"):
        export_pretrained(other, results, tmp_path / "out", config="c", commit="c")
    assert not (tmp_path / "out").exists()
    copy = checkpoint.with_name("copy.ckpt")  # the tested checkpoint by content, under a new name
    copy.write_bytes(checkpoint.read_bytes())
    entry = export_pretrained(copy, results, tmp_path / "out", config="c", commit="c")
    assert entry["source"] == "copy.ckpt"


def test_try_names_what_is_shipped_for_an_unknown_policy(capsys):
    assert cli_main(["try", "--task", "block-insertion", "--method", "nope"]) == 2
    error = capsys.readouterr().err
    assert "no pretrained nope policy for block-insertion" in error
    assert "block-insertion/mira" in error


def test_try_refuses_an_unwritable_video_folder_before_running_anything(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert cli_main(["try", "--video", str(blocker / "videos")]) == 2
    error = capsys.readouterr().err
    assert "--video" in error and "is not a folder" in error


ANOTHER_WORLD = "0" * 16  # the fingerprint of a world no shipped policy was trained in


def refuse_to_load(*args, **kwargs):
    raise AssertionError("a policy of another world was loaded")


def test_try_refuses_a_shipped_policy_of_another_world_by_name(monkeypatch, capsys):
    monkeypatch.setattr(pretrained_module, "world_fingerprint", lambda: ANOTHER_WORLD)
    monkeypatch.setattr(pretrained_module, "load_checkpoint", refuse_to_load)
    (entry,) = [e for e in SHIPPED if (e["task"], e["method"]) == ("block-insertion", "mira")]
    assert cli_main(["try", "--task", "block-insertion", "--method", "mira"]) == 2
    error = capsys.readouterr().err
    assert "block-insertion/mira (block-insertion-mira.ckpt)" in error
    assert f"trained in world {entry['test']['world']}" in error
    assert f"this package's world is {ANOTHER_WORLD}" in error
    assert "re-shipped" in error and "nerf-transporter run-cell" in error


def test_try_list_marks_the_shipped_policies_of_another_world(monkeypatch, capsys):
    world = SHIPPED[0]["test"]["world"]
    monkeypatch.setattr(pretrained_module, "world_fingerprint", lambda: world)
    assert cli_main(["try", "--list"]) == 0
    out = capsys.readouterr().out
    assert shipped_table(SHIPPED) in out  # the table as the README has it, then the marks
    marked = [line for line in out.splitlines() if line.startswith("- ")]
    foreign = [e for e in SHIPPED if e["test"]["world"] != world]
    assert marked == [
        f"- {e['task']}/{e['method']} ({e['file']}): world {e['test']['world']}" for e in foreign
    ]
    monkeypatch.setattr(pretrained_module, "world_fingerprint", lambda: ANOTHER_WORLD)
    assert cli_main(["try", "--list"]) == 0
    out = capsys.readouterr().out
    assert len([line for line in out.splitlines() if line.startswith("- ")]) == len(SHIPPED)


def test_a_policy_is_run_only_in_the_world_it_was_trained_in():
    entry = {"task": "block-insertion", "method": "mira", "file": "x.ckpt", "commit": "abc1234"}
    check_world(entry | {"test": {"world": "1" * 16}}, "1" * 16)  # its own world: no objection
    with pytest.raises(ForeignWorldError, match="trained in world 1{16}, .* is 2{16}"):
        check_world(entry | {"test": {"world": "1" * 16}}, "2" * 16)
    with pytest.raises(ForeignWorldError, match="world unrecorded"):  # no world: not this one
        check_world(entry | {"test": {}}, "2" * 16)


def synthetic_observation(input_kind: str, pixel_size: float) -> dict:
    """Random images of the policy's size (or a random state): enough to act on."""
    rng = np.random.default_rng(0)
    shape = g.image_shape(pixel_size)
    if input_kind == "heightmap":
        return {
            "heightmap": {
                "colour": rng.integers(0, 256, (*shape, 3), dtype=np.uint8),
                "height": rng.uniform(0, 0.05, shape).astype(np.float32),
            }
        }
    views = g.view_grid("normal")
    return {
        "imagery": {
            "colour": rng.integers(0, 256, (len(views), *shape, 3), dtype=np.uint8),
            "height": rng.uniform(0, 0.05, (len(views), *shape)).astype(np.float16),
            "views": views,
        }
    }


SHIPPED = load_manifest(PRETRAINED_DIR)


def test_the_quickstart_policies_are_shipped():
    shipped = {(entry["task"], entry["method"]) for entry in SHIPPED}
    assert ("block-insertion", "mira") in shipped
    assert ("block-insertion", "transporter_se2") in shipped


@pytest.mark.parametrize("entry", SHIPPED, ids=lambda e: f"{e['task']}-{e['method']}")
def test_a_shipped_policy_loads_weights_only_and_acts(entry):
    path = PRETRAINED_DIR / entry["file"]
    assert file_sha256(path) == entry["sha256"]
    assert path.stat().st_size < 8e6  # the table's full-resolution models: 1.9 M float32 weights
    state = torch.load(path, map_location="cpu", weights_only=True)
    assert state["provenance"]["test"]["episodes"] >= 10
    model, datamodule = load_checkpoint(path, torch.device("cpu"))
    assert (model.name, datamodule.task) == (entry["method"], entry["task"])
    action = model.act(synthetic_observation(model.input_kind, model.pixel_size))
    # on the table: inside the workspace, give or take a tilted view's margin
    low, high = g.BOUNDS[:2, 0] - 0.1, g.BOUNDS[:2, 1] + 0.1
    for position, _ in (action["pick"], action["place"]):
        assert np.all(low <= position[:2]) and np.all(position[:2] <= high)


def test_the_readme_states_the_shipped_policies_as_measured():
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    assert shipped_table(SHIPPED) in readme, "README: paste `nerf-transporter try --list`"


def test_testing_a_shipped_policy_writes_its_results_to_the_run_folder(tmp_path):
    shipped = PRETRAINED_DIR / policy_file_name("block-insertion", "mira")
    assert results_directory(str(shipped), str(tmp_path)) == tmp_path
    copy = tmp_path / "copy" / shipped.name
    assert results_directory(str(copy), str(tmp_path / "run")) == copy.parent
    assert results_directory(None, str(tmp_path)) == tmp_path
