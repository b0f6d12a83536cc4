"""`nerf-transporter export-pretrained CHECKPOINT RECORD --config ... --commit ...`: a checkpoint
is shipped only with an error-free test record of itself (known by content), checked as the cell
loader checks cells, into the package folder of the checkout it runs in; anything else ends with
one line naming the file and the problem (exit status 2), before anything is written."""

import json
import shutil
from pathlib import Path

import pytest
import torch

from nerf_transporter.cli import main as cli_main
from nerf_transporter.data.episode import file_sha256
from nerf_transporter.evaluation.metrics import summarize
from nerf_transporter.experiments import pretrained as pretrained_module
from nerf_transporter.experiments.pretrained import load_manifest
from tests.experiments.test_pretrained import results_of, trained_run

PACKAGE = Path("src/nerf_transporter/pretrained")
POLICY = "block-insertion-gt_state_mlp.ckpt"


@pytest.fixture(scope="module")
def tested_run(tmp_path_factory):
    """A 2-step gt_state_mlp run with its checkpoint and the results file of its test on seeds
    1 and 3 (shared: the tests copy what they change)."""
    folder = tmp_path_factory.mktemp("tested")
    checkpoint = trained_run(folder)
    return checkpoint, results_of(checkpoint, [1, 3])


@pytest.fixture
def checkout(tmp_path, monkeypatch, tested_run):
    """A checkout of the project (its package's pretrained folder, with a manifest of one other
    policy) holding a copy of the tested run; the installed package lies elsewhere. The working
    directory is the checkout."""
    root = tmp_path / "checkout"
    (root / PACKAGE).mkdir(parents=True)
    other = {"file": "stacking-kits-mira.ckpt", "task": "stacking-kits", "method": "mira"}
    (root / PACKAGE / "manifest.json").write_text(json.dumps({"policies": [other]}))
    checkpoint, results = tested_run
    run = root / "logs" / "run"
    shutil.copytree(checkpoint.parents[1], run)
    installed = tmp_path / "site-packages" / "nerf_transporter" / "pretrained"
    installed.mkdir(parents=True)
    monkeypatch.setattr(pretrained_module, "PRETRAINED_DIR", installed)
    monkeypatch.chdir(root)
    return root, run / "checkpoints" / checkpoint.name, run / "checkpoints" / results.name


def export(checkpoint, record, *options):
    argv = ["export-pretrained", str(checkpoint), str(record), "--config", "tiny.yaml"]
    return cli_main([*argv, "--commit", "abc1234", *options])


def edited(path, edit):
    record = json.loads(path.read_text())
    edit(record)
    path.write_text(json.dumps(record))
    return path


def refused(capsys, *parts):
    """The one line export-pretrained printed on stderr, holding each of `parts`."""
    err = capsys.readouterr().err
    assert err.startswith("nerf-transporter export-pretrained: ") and err.count("\n") == 1, err
    for part in parts:
        assert str(part) in err, err


def test_export_ships_into_the_package_folder_of_the_checkout_it_runs_in(checkout, capsys):
    root, checkpoint, record = checkout
    assert export(checkpoint, record) == 0
    shipped = root / PACKAGE / POLICY
    out = capsys.readouterr().out
    tested = json.loads(record.read_text())
    assert out.startswith(f"wrote {shipped} (") and out.rstrip().endswith(
        f"{round(100 * tested['success_rate'])}% (2, "
        f"{round(100 * tested['ci_low'])}-{round(100 * tested['ci_high'])})"
    )
    entries = load_manifest(root / PACKAGE)
    assert [(e["task"], e["method"]) for e in entries] == [
        ("block-insertion", "gt_state_mlp"),
        ("stacking-kits", "mira"),
    ]
    assert entries[0]["sha256"] == file_sha256(shipped) and entries[0]["test"]["seeds"] == [1, 3]
    state = torch.load(shipped, map_location="cpu", weights_only=True)
    assert state["provenance"]["commit"] == "abc1234"
    assert not any(pretrained_module.PRETRAINED_DIR.iterdir())  # the installed copy: untouched


def test_export_from_below_the_checkout_and_elsewhere_with_out(checkout, tmp_path, monkeypatch):
    root, checkpoint, record = checkout
    monkeypatch.chdir(root / "logs" / "run")
    assert export(checkpoint.resolve(), record.resolve()) == 0
    assert (root / PACKAGE / POLICY).is_file()
    out = tmp_path / "shipped"
    assert export(checkpoint.resolve(), record.resolve(), "--out", str(out)) == 0
    assert [e["file"] for e in load_manifest(out)] == [POLICY]


def test_export_outside_a_checkout_needs_out(checkout, tmp_path, monkeypatch, capsys):
    _, checkpoint, record = checkout
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    monkeypatch.chdir(outside)
    assert export(checkpoint.resolve(), record.resolve()) == 2
    refused(capsys, "lies in no checkout of nerf-transporter", "give --out")
    blocker = outside / "a-file"
    blocker.write_text("")
    assert export(checkpoint.resolve(), record.resolve(), "--out", str(blocker)) == 2
    refused(capsys, f"--out {blocker} cannot be written")


def another_run(checkpoint: Path) -> Path:
    """A checkpoint of the same name in another run: other weights."""
    run = checkpoint.parents[2] / "another"
    shutil.copytree(checkpoint.parents[1], run)
    other = run / "checkpoints" / checkpoint.name
    state = torch.load(other, map_location="cpu", weights_only=True)
    for tensor in state["state_dict"].values():
        tensor.add_(1.0)
    torch.save(state, other)
    return other


def test_a_checkpoint_is_shipped_only_with_the_record_of_its_own_test(checkout, capsys):
    root, checkpoint, record = checkout
    other = another_run(checkpoint)
    assert export(other, record) == 2  # the same file name, other weights
    refused(capsys, record, f"tests another checkpoint than {other}")
    # a record without its checkpoint's hash (written before records held it): the file it names
    old = edited(record, lambda r: r.pop("checkpoint_sha256"))
    assert export(other, old) == 2
    refused(capsys, f"tests another checkpoint than {other}")
    edited(old, lambda r: r.update(checkpoint="logs/gone/step2.ckpt"))
    assert export(checkpoint, old) == 2
    refused(capsys, old, "names no checkpoint file here (logs/gone/step2.ckpt)")
    assert not (root / PACKAGE / POLICY).exists()


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (
            lambda r: r.update(successes=150, episodes=3),
            "150 successes of 3 episodes",
        ),
        (lambda r: r.update(world="0" * 16), f"was measured in world {'0' * 16}"),
        (lambda r: r.update(split="validation"), 'its split is "validation"'),
        (
            lambda r: r.update(
                episode_results=[r["episode_results"][0] | {"error": "E", "outcome": "error"}]
                + r["episode_results"][1:],
                **summarize([r["episode_results"][0] | {"error": "E"}] + r["episode_results"][1:]),
            ),
            "is not an error-free test with its episodes (1 episodes, 1 erred)",
        ),
        (
            lambda r: r.update(imagery_options={"colour_init": "table"}),
            "tested the policy on an imagery candidate (colour_init=table)",
        ),
    ],
    ids=["counts", "another-world", "validation", "erred", "imagery-candidate"],
)
def test_a_record_the_cell_loader_refuses_is_not_shipped(checkout, capsys, edit, problem):
    root, checkpoint, record = checkout
    assert export(checkpoint, edited(record, edit)) == 2
    refused(capsys, record, problem)
    assert not (root / PACKAGE / POLICY).exists()


def test_a_truncated_checkpoint_and_a_malformed_manifest_are_named(checkout, capsys):
    root, checkpoint, record = checkout
    manifest = root / PACKAGE / "manifest.json"
    for text in ("{", '{"policies": {"a": 1}}', '{"policies": [1]}', "[" * 100_000):
        manifest.write_text(text)
        assert export(checkpoint, record) == 2
        refused(capsys, f"{manifest} is not a manifest of pretrained policies")
    assert not (root / PACKAGE / POLICY).exists()
    manifest.unlink()
    checkpoint.write_bytes(checkpoint.read_bytes()[:2000])  # truncated after its test
    # a record written before records held the hash: it names the checkpoint file, now truncated
    old = edited(
        record, lambda r: r.pop("checkpoint_sha256") and r.update(checkpoint=str(checkpoint))
    )
    assert export(checkpoint, old) == 2
    refused(capsys, f"{checkpoint} is not a readable weights-only checkpoint")
    assert not (root / PACKAGE / POLICY).exists()
