"""Pretrained policies shipped in the package (`nerf_transporter/pretrained/`), and the commands
around them: `nerf-transporter try` (evaluate one on a few test episodes and write videos) and
`nerf-transporter export-pretrained` (reduce a trained checkpoint to a shipped policy).

A shipped policy is a Lightning checkpoint reduced to what acting needs: the weights, the method's
and the DataModule's hyper-parameters, the step, and a `provenance` entry (commit, config,
validation and test success). Only tensors and plain values remain, so it loads with
`torch.load(..., weights_only=True)`, with `lightning test --ckpt_path` and with
`experiments.checkpoints.load_checkpoint`. `pretrained/manifest.json` lists them with the same
provenance.

`export-pretrained` takes a checkpoint and the record of its test (`lightning test`'s results
file, `evaluate-checkpoints --split test`'s record, or a run-cell cell), loaded with the checks of
`evaluation/cells.py` (counts, seeds, this checkout's world); the record must be an error-free test
of that very checkpoint, known by its content: the SHA-256 the record holds
(`checkpoint_sha256`), else that of the file the record names. It writes into the package folder
of the checkout it runs in (the nearest folder above the working directory holding
`src/nerf_transporter/pretrained/`), whichever copy of the package is installed; `--out` elsewhere.
The manifest is read, and the checkpoint loaded, before anything is written.

A shipped policy belongs to the world it was trained and tested in (`provenance.test.world`, the
world fingerprint of `sim.fingerprint`): in another world its actions and its measured success mean
nothing, so `try` refuses it by name (exit status 2), and `try --list` marks it, until it is
re-shipped from a table measured in this world.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from pathlib import Path
from typing import Any

import torch
import yaml

from nerf_transporter.atomic import unwritable_reason, write_file, write_json
from nerf_transporter.console import HelpFormatter
from nerf_transporter.data.episode import file_sha256
from nerf_transporter.evaluation.metrics import cell
from nerf_transporter.evaluation.rollout import DEFAULT_CACHE_DIR, EpisodeResult
from nerf_transporter.evaluation.testing import checkpoint_step, evaluate_policy
from nerf_transporter.experiments.cells import load_record
from nerf_transporter.experiments.checkpoints import (
    check_checkpoint_classes,
    config_callbacks,
    load_checkpoint,
    validation_score,
)
from nerf_transporter.pretrained import PRETRAINED_DIR
from nerf_transporter.sim.fingerprint import components_read, same_world, world_fingerprint
from nerf_transporter.splits import split_seed

MANIFEST = "manifest.json"
# the package folder of shipped policies inside a checkout (`--out`'s default: the checkout's own)
CHECKOUT_PRETRAINED = Path("src/nerf_transporter/pretrained")
ENTRY_NAMES = ("task", "method", "file")  # the fields naming a manifest entry
# what a shipped policy keeps of a Lightning checkpoint (optimizer and loop states are dropped)
KEPT_KEYS = (
    "state_dict",
    "hyper_parameters",
    "hparams_name",
    "datamodule_hyper_parameters",
    "datamodule_hparams_name",
    "global_step",
    "epoch",
    "pytorch-lightning_version",
)
TEST_FIGURES = ("episodes", "successes", "success_rate", "ci_low", "ci_high", "errors", "setting")


def policy_file_name(task: str, method: str) -> str:
    return f"{task}-{method}.ckpt"


def load_manifest(folder: Path = PRETRAINED_DIR) -> list[dict[str, Any]]:
    """The shipped policies' entries (empty when none is shipped); a ValueError naming the file
    where it is no manifest: no JSON object whose `policies` are entries naming their task,
    method and file."""
    path = folder / MANIFEST
    if not path.exists():
        return []
    problem = "its policies are not a list of entries naming their task, method and file"
    try:
        content = json.loads(path.read_text())
    except (OSError, ValueError) as error:  # ValueError: not JSON (or not text)
        problem = str(error)
    except RecursionError:
        problem = "nested too deeply"
    else:
        policies = content.get("policies") if isinstance(content, dict) else None
        if isinstance(policies, list) and all(
            isinstance(entry, dict) and all(isinstance(entry.get(key), str) for key in ENTRY_NAMES)
            for entry in policies
        ):
            return policies
    raise ValueError(f"{path} is not a manifest of pretrained policies: {problem}")


class ForeignWorldError(ValueError):
    """A shipped policy was trained in another world than this package's."""


def find_entry(task: str, method: str, folder: Path = PRETRAINED_DIR) -> dict[str, Any]:
    """The manifest entry of the shipped policy for (task, method); a ValueError lists the shipped
    ones otherwise."""
    entries = load_manifest(folder)
    for entry in entries:
        if entry["task"] == task and entry["method"] == method:
            return entry
    shipped = ", ".join(f"{e['task']}/{e['method']}" for e in entries) or "none"
    raise ValueError(f"no pretrained {method} policy for {task} is shipped (shipped: {shipped})")


def find_policy(task: str, method: str, folder: Path = PRETRAINED_DIR) -> Path:
    """The shipped policy for (task, method); a ValueError lists the shipped ones otherwise."""
    return folder / find_entry(task, method, folder)["file"]


def policy_world(entry: dict[str, Any]) -> str | None:
    """The world fingerprint a shipped policy was trained and tested in (None: not recorded)."""
    return (entry.get("test") or {}).get("world")


def trained_in(entry: dict[str, Any], world: str) -> bool:
    """Whether the shipped policy of `entry` was trained in `world` (in what it read of it)."""
    return same_world(policy_world(entry), world, components_read(entry.get("imagery")))


def foreign_world_text(entry: dict[str, Any], world: str) -> str:
    """Why the shipped policy of `entry` is not run in `world`, and what to do instead."""
    name = f"{entry['task']}/{entry['method']} ({entry['file']})"
    trained = policy_world(entry) or "unrecorded"
    commit = str(entry.get("commit") or "")[:7]
    return (
        f"the shipped policy {name} was trained in world {trained}, and this package's world is "
        f"{world}: its actions and its measured success belong to that other world, so it is not "
        "run here. The shipped policies are re-shipped from the results table measured in this "
        "world; until then, train one here (`nerf-transporter run-cell --task "
        f"{entry['task']} --method {entry['method']}`, then `nerf-transporter export-pretrained`)"
        + (f", or try this one at its own commit (`git checkout {commit}`)" if commit else "")
    )


def check_world(entry: dict[str, Any], world: str | None = None) -> None:
    """Raise a ForeignWorldError naming the policy where it was trained in another world than
    `world` (default: this package's)."""
    world = world_fingerprint() if world is None else world
    if not trained_in(entry, world):
        raise ForeignWorldError(foreign_world_text(entry, world))


def checkout_pretrained_dir(folder: Path | None = None) -> Path | None:
    """The package folder of shipped policies of the checkout `folder` (default: the working
    directory) lies in: `src/nerf_transporter/pretrained` of the nearest folder above it that
    holds one; None outside a checkout."""
    folder = (folder or Path.cwd()).absolute()
    for parent in (folder, *folder.parents):
        if (parent / CHECKOUT_PRETRAINED).is_dir():
            return parent / CHECKOUT_PRETRAINED
    return None


def tested_checkpoint_hash(record: dict[str, Any]) -> str:
    """The content hash of the checkpoint a test record (or a cell) tested: the one it holds,
    else that of the file it names, which must be there."""
    if record.get("checkpoint_sha256"):
        return record["checkpoint_sha256"]
    named = record.get("checkpoint")
    named = named.get("path") if isinstance(named, dict) else named
    if not named or not Path(named).is_file():
        raise ValueError(
            f"{record['path']} names no checkpoint file here ({named}) and holds no "
            "checkpoint_sha256, so the checkpoint it tested cannot be known: run export-pretrained "
            "from the folder it was tested in"
        )
    return file_sha256(named)


def check_test_of(record: dict[str, Any], checkpoint: Path) -> None:
    """ValueError unless `record` is an error-free test, with its episodes, of `checkpoint`
    itself (by content: `tested_checkpoint_hash`), on the imagery it was trained on."""
    where = record["path"]
    if record["errors"] or not record["episodes"] or not record.get("episode_results"):
        raise ValueError(
            f"{where} is not an error-free test with its episodes ({record['episodes']} episodes, "
            f"{record['errors']} erred)"
        )
    if tested_checkpoint_hash(record) != file_sha256(checkpoint):
        raise ValueError(
            f"{where} tests another checkpoint than {checkpoint} (their contents differ); export "
            "the checkpoint together with the record of its own test"
        )
    if record.get("imagery_options"):
        options = ", ".join(f"{k}={v}" for k, v in sorted(record["imagery_options"].items()))
        raise ValueError(
            f"{where} tested the policy on an imagery candidate ({options}), not on the imagery "
            "it was trained on; export it with the record of a test on its own imagery"
        )


def read_checkpoint(checkpoint: Path) -> dict[str, Any]:
    """The checkpoint's content, tensors and plain values only; a ValueError naming it where it
    is no readable checkpoint (truncated, not one, or holding other objects)."""
    try:
        state = torch.load(checkpoint, map_location="cpu", weights_only=True)
    except Exception as error:  # truncated, not a checkpoint, or refused by weights_only
        raise ValueError(
            f"{checkpoint} is not a readable weights-only checkpoint: {error}"
        ) from error
    if not isinstance(state, dict) or not {"state_dict", "global_step"} <= state.keys():
        raise ValueError(f"{checkpoint} is no checkpoint of `lightning fit` (no weights or step)")
    return state


def run_config(checkpoint: Path) -> dict[str, Any]:
    """The resolved config LightningCLI saved in the checkpoint's run folder."""
    path = checkpoint.resolve().parent.parent / "config.yaml"
    if not path.is_file():
        raise ValueError(f"{checkpoint} is not in a run folder with its config.yaml ({path})")
    try:
        config = yaml.safe_load(path.read_text())
    except (OSError, ValueError, yaml.YAMLError) as error:
        raise ValueError(f"{path} is not a readable run config: {error}") from error
    if not isinstance(config, dict):
        raise ValueError(f"{path} is not a run config (no mapping)")
    return config


def validation_figures(checkpoint: dict[str, Any], config: dict[str, Any]) -> dict[str, Any]:
    """The closed-loop validation success the checkpoint was chosen by (its ModelCheckpoint's
    score when it was saved) and the episodes of a validation round (the run's config)."""
    rounds = config_callbacks(config, "SuccessRateCallback")
    episodes = rounds[0].get("init_args", {}).get("episodes") if rounds else None
    return {"success_rate": validation_score(checkpoint), "episodes": episodes}


def export_pretrained(
    checkpoint: Path,
    results: Path,
    out_folder: Path,
    *,
    config: str,
    commit: str,
) -> dict[str, Any]:
    """Write `<task>-<method>.ckpt` into `out_folder` from a trained checkpoint and the record of
    its test (see the module docstring), and add (or replace) its entry in the folder's manifest;
    a ValueError naming the file and the problem, before anything is written, otherwise. A
    checkpoint that names classes other than this package's is refused before it is read."""
    state = read_checkpoint(checkpoint)
    check_checkpoint_classes(checkpoint)  # before anything it names could be imported
    record = load_record(results)
    check_test_of(record, checkpoint)
    entries = load_manifest(out_folder)
    resolved = run_config(checkpoint)
    provenance = {
        "task": record["task"],
        "method": record["method"],
        "imagery": record.get("imagery"),
        "config": config,
        "commit": commit,
        "trained_steps": resolved.get("trainer", {}).get("max_steps"),
        "step": int(state["global_step"]),
        "validation": validation_figures(state, resolved),
        "test": {key: record.get(key) for key in TEST_FIGURES}
        | {"seeds": [r["seed"] for r in record["episode_results"]], "world": record["world"]},
        "source": checkpoint.name,
    }
    reduced = {key: state[key] for key in KEPT_KEYS if key in state} | {"provenance": provenance}
    name = policy_file_name(record["task"], record["method"])
    buffer = io.BytesIO()
    torch.save(reduced, buffer)
    buffer.seek(0)
    torch.load(buffer, map_location="cpu", weights_only=True)  # ships only plain data
    write_file(out_folder / name, lambda file: file.write(buffer.getvalue()))
    entry = {"file": name, "bytes": (out_folder / name).stat().st_size}
    entry |= {"sha256": file_sha256(out_folder / name)} | provenance
    entries = [e for e in entries if (e["task"], e["method"]) != (entry["task"], entry["method"])]
    entries = sorted([*entries, entry], key=lambda e: (e["task"], e["method"]))
    write_json(out_folder / MANIFEST, {"policies": entries})
    return entry


def try_policy(
    task: str,
    method: str,
    episodes: int,
    video_dir: Path | None,
    *,
    folder: Path = PRETRAINED_DIR,
    cache_dir: str | None = DEFAULT_CACHE_DIR,
    workers: int | None = None,
) -> dict[str, Any]:
    """Evaluate a shipped policy on the first `episodes` test seeds; a results record. A policy
    trained in another world is refused (ForeignWorldError, naming it)."""
    entry = find_entry(task, method, folder)
    check_world(entry)
    path = folder / entry["file"]
    model, datamodule = load_checkpoint(path, torch.device("cpu"))
    return evaluate_policy(
        model,
        datamodule,
        [split_seed("test", index) for index in range(episodes)],
        split="test",
        cache_dir=cache_dir,
        workers=workers,
        checkpoint=str(path),
        global_step=checkpoint_step(path),
        desc=f"{task} {method}",
        video_dir=video_dir,
    )


def shipped_table(entries: list[dict[str, Any]]) -> str:
    """Markdown table of the shipped policies: config, commit, step and measured success."""
    lines = [
        "| task | method | config | commit | step | test success (n, 95% CI) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for e in entries:
        lines.append(
            f"| {e['task']} | {e['method']} | `{e['config']}` | {e['commit'][:7]} | {e['step']} "
            f"| {cell(e['test'])} |"
        )
    return "\n".join(lines)


def foreign_world_note(entries: list[dict[str, Any]], world: str) -> str | None:
    """The shipped policies trained in another world than `world`, one line each, under a
    headline; None where all were trained in it."""
    foreign = [entry for entry in entries if not trained_in(entry, world)]
    if not foreign:
        return None
    lines = [
        f"- {e['task']}/{e['method']} ({e['file']}): world {policy_world(e) or 'unrecorded'}"
        for e in foreign
    ]
    return (
        f"From another world (this package's world is {world}; `try` refuses these until they "
        "are re-shipped from the table measured in this world):\n" + "\n".join(lines)
    )


def try_main(argv: list[str] | None = None) -> int:
    """`nerf-transporter try`: a shipped policy on a few test episodes, with videos."""
    parser = argparse.ArgumentParser(
        prog="nerf-transporter try",
        description="Evaluate a pretrained policy shipped with the package on the first test "
        "episodes and write one captioned mp4 per episode. No training or data needed.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--task", default="block-insertion", help="task of the policy")
    parser.add_argument("--method", default="mira", help="method of the policy")
    parser.add_argument("--episodes", type=int, default=2, help="test episodes to run")
    parser.add_argument("--video", type=Path, default=Path("videos/try"), help="mp4 folder")
    parser.add_argument(
        "--eval-workers", type=int, default=None, help="processes (default: one per core)"
    )
    parser.add_argument(
        "--list",
        action="store_true",
        help="list the shipped policies (marking those from another world) and stop",
    )
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")
    reason = None if args.list else unwritable_reason(args.video)
    if reason is not None:
        print(
            f"nerf-transporter try: --video {args.video} cannot be written ({reason})",
            file=sys.stderr,
        )
        return 2
    try:
        entries = load_manifest()
        if args.list:
            print(shipped_table(entries))
            note = foreign_world_note(entries, world_fingerprint())
            if note is not None:
                print(f"\n{note}")
            return 0
        record = try_policy(
            args.task, args.method, args.episodes, args.video, workers=args.eval_workers
        )
    except ValueError as error:
        print(f"nerf-transporter try: {error}", file=sys.stderr)
        return 2
    for result in record["episode_results"]:
        print(f"seed {result['seed']}: {EpisodeResult.from_json(result).outcome_text()}")
    print(f"{args.task} {args.method}: {cell(record)} in {record['wall_s']:.0f} s")
    videos = [result["video"] for result in record["episode_results"] if result.get("video")]
    print(f"videos: {len(videos)} of {len(record['episode_results'])} episodes in {args.video}/")
    return 0


def export_main(argv: list[str] | None = None) -> int:
    """`nerf-transporter export-pretrained`: a trained checkpoint -> a shipped policy."""
    parser = argparse.ArgumentParser(
        prog="nerf-transporter export-pretrained",
        description="Reduce a trained checkpoint to weights and hyper-parameters, with its "
        "provenance and the test success of its results file, into the pretrained folder "
        "(and its manifest.json).",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("checkpoint", type=Path, help="a checkpoint written by `lightning fit`")
    parser.add_argument(
        "results",
        type=Path,
        help="the record of its test: `lightning test`'s results file, or for a run-cell fit "
        "<run>/evaluation/<checkpoint>-test-normal.json or its cell; the record must name the "
        "checkpoint (by content) and be of this checkout's world",
    )
    parser.add_argument("--config", required=True, help="the config(s) the run was trained with")
    parser.add_argument("--commit", required=True, help="the git commit the run was trained at")
    parser.add_argument(
        "--out",
        type=Path,
        help="the folder to write the policy and its manifest entry into (default: "
        f"{CHECKOUT_PRETRAINED} of the checkout the working directory lies in, whichever copy of "
        "the package is installed)",
    )
    args = parser.parse_args(argv)
    try:
        for path in (args.checkpoint, args.results):
            if not path.is_file():
                raise ValueError(f"no such file: {path}")
        out = args.out or checkout_pretrained_dir()
        if out is None:
            raise ValueError(
                f"the working directory lies in no checkout of nerf-transporter (no "
                f"{CHECKOUT_PRETRAINED} above it): run it in the checkout to ship from, or give --out"
            )
        if reason := unwritable_reason(out):
            raise ValueError(f"--out {out} cannot be written: {reason}")
        entry = export_pretrained(
            args.checkpoint, args.results, out, config=args.config, commit=args.commit
        )
    except ValueError as error:
        print(f"nerf-transporter export-pretrained: {error}", file=sys.stderr)
        return 2
    print(f"wrote {out / entry['file']} ({entry['bytes'] / 1e6:.2f} MB): {cell(entry['test'])}")
    return 0
