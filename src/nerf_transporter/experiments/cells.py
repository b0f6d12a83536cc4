"""Cell files of the results table and test records, checked before any of their numbers is used.

`report`, `compare-cells`, `failures` and `run-cell`'s skip check read them here. A cell is what
`run-cell` writes (`<results>/<column>/<row>.json`, with its `protocol`); a test record is what
`lightning test` (`results-<checkpoint>.json`) and `evaluate-checkpoints --split test`
(`<run>/evaluation/<checkpoint>-test-<setting>.json`) write. A cell tested in another setting than
its policy was trained in (`run-cell --test-setting`) names its fit: its protocol holds
`trained_setting` and `fit_protocol_id` (the id of the protocol it was fitted under: its own, with
the training setting), and its `fit` the same id, the fit's run folder and the tested checkpoint,
which must be the cell's. Either file is refused, naming the file
and the problem, where a field has the wrong type, the counts disagree (successes <= episodes,
the counts of its episode records, the Wilson interval recomputed; the same for the strict 6-DoF
count `strict_successes` where present), an outcome is not a real boolean or one of the outcome
strings, a seed repeats or is no test seed (odd, below the validation seeds: `splits.py`) or the
seeds are not its `test_seeds`, its confidence is not the 95% the tables state, a validation
round's success rate is no rate of the protocol's episodes, it names a task, setting, method or
imagery this package does not have, a number is beyond 2^53 or the JSON nests too deeply to
read, or it was measured in another world than the one expected: this checkout's
(`sim/fingerprint.py`), or, for a file under `<results>/archive/world-<fingerprint>/` (the cells
of an earlier world, kept with the layout of `results/`), that fingerprint.

`find_records` reads the folders `report` is given: the cells of a folder of cells (each where
run-cell writes it, else refused), else, in a folder of runs such as `logs/`, its test records
(`results*.json`). A test record under a folder of cells is left out: it is never taken for a
cell of the table. The archived worlds below a folder come apart, one `Archive` each, and so do
the archived recipes: this world's cells measured under a training recipe the table has since
left, kept under `<results>/archive/recipe-<name>/` with the layout of `results/`.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import math
import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

from nerf_transporter.data.observation import IMAGERY_KINDS
from nerf_transporter.evaluation.metrics import CONFIDENCE, wilson_interval
from nerf_transporter.evaluation.view_search import VIEW_SEARCH_FIGURES
from nerf_transporter.sim.fingerprint import components_read, same_world, world_fingerprint
from nerf_transporter.sim.tasks import SETTINGS, TASKS
from nerf_transporter.splits import VALIDATION_OFFSET, split_of_seed

TEST_RECORD_GLOB = "results*.json"  # lightning test's records, one per tested checkpoint
ARCHIVE = "archive"  # <results>/archive/world-<fingerprint>/: the cells of an earlier world
ARCHIVED_WORLD = re.compile(r"world-([0-9a-f]{16})")
# <results>/archive/recipe-<name>/: this world's cells measured under an earlier training recipe
ARCHIVED_RECIPE = re.compile(r"recipe-([a-z0-9][a-z0-9._-]*)")
OUTCOMES = ("success", "failure", "error")
TOLERANCE = 1e-9  # how far a stored interval may lie from the one recomputed from its counts
LARGEST_INT = 2**53  # the largest count or seed a record may hold (beyond it no float is exact)
# the methods' names (`methods.METHODS`, which imports Lightning: too slow for `report`)
METHOD_NAMES = ("mira", "transporter_se2", "transporter_se3", "form2fit", "gt_state_mlp")


class CellFileError(ValueError):
    """A file that is not a valid cell or test record (the message names it and the problem)."""


def row_key(method: str, imagery: str | None) -> str:
    """The table row of a record: the method, `<method>-oracle` where it ran on oracle imagery."""
    return f"{method}-oracle" if imagery == "oracle" else method


def column_folder(task: str, setting: str, trained: str = "normal") -> str:
    """The folder of a column's cells under `results/`, `<task>[-<setting>][-trained-<trained>]`
    (tested in `setting`, trained in `trained`; the suffix only for a policy not trained Normal),
    and of a fit's runs under `logs/cells/` (`setting`: the one it trains in)."""
    folder = task if setting == "normal" else f"{task}-{setting}"
    return folder if trained == "normal" else f"{folder}-trained-{trained}"


def trained_setting(record: dict[str, Any]) -> str:
    """The setting a record's policy was trained in: its protocol's, else its test record's,
    else (records written before either said) the setting it was tested in."""
    protocol = record.get("protocol") or {}
    return protocol.get("trained_setting", record.get("trained_setting", record["setting"]))


# a cross-setting cell's protocol keys beyond those of its fit's protocol
CROSS_KEYS = ("trained_setting", "fit_protocol_id")


def protocol_id(protocol: dict[str, Any]) -> str:
    """12 hex digits naming a protocol (its fit folder)."""
    return hashlib.sha256(json.dumps(protocol, sort_keys=True).encode()).hexdigest()[:12]


def cross_protocol(fit: dict[str, Any], test_setting: str) -> dict[str, Any]:
    """The protocol of a cell testing the policy fitted under the protocol `fit` in
    `test_setting`: the fit's, tested there, naming the fit's setting and protocol id."""
    return fit | {
        "setting": test_setting,
        "trained_setting": fit["setting"],
        "fit_protocol_id": protocol_id(fit),
    }


def fit_protocol(protocol: dict[str, Any]) -> dict[str, Any]:
    """The protocol a cell's policy was fitted under: its own, or a cross-setting cell's fit's."""
    if "trained_setting" not in protocol:
        return protocol
    fit = {key: value for key, value in protocol.items() if key not in CROSS_KEYS}
    return fit | {"setting": protocol["trained_setting"]}


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and abs(value) <= LARGEST_INT


def _is_number(value: Any) -> bool:
    return _is_int(value) or (isinstance(value, float) and math.isfinite(value))


# a field's kind -> (test, what it is called); a kind ending in "?" also takes null
KINDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "int": (_is_int, "an integer of at most 2^53"),
    "number": (_is_number, "a finite number"),
    "bool": (lambda v: isinstance(v, bool), "true or false"),
    "str": (lambda v: isinstance(v, str), "a string"),
    "list": (lambda v: isinstance(v, list), "a list"),
    "dict": (lambda v: isinstance(v, dict), "an object"),
}
# the fields of every cell and test record, then those of cells, protocols, test records and
# episode records: field -> kind; the optional ones may be absent
RECORD_FIELDS = {
    "method": "str",
    "task": "str",
    "setting": "str",
    "world": "str",
    "episodes": "int",
    "successes": "int",
    "ci_low": "number",
    "ci_high": "number",
}
RECORD_OPTIONAL = {
    "imagery": "str?",
    "trained_setting": "str",
    "split": "str",
    "created": "str",
    "episode_results": "list",
    "errors": "int",
    "erred_seeds": "list",
    "confidence": "number",
    "success_rate": "number?",
    "strict_successes": "int?",
    "strict_success_rate": "number?",
    "strict_ci_low": "number?",
    "strict_ci_high": "number?",
}
CELL_FIELDS = {"protocol": "dict", "checkpoint": "dict"}
CELL_OPTIONAL = {
    "validation": "list",
    "machine": "dict",
    "overlays": "list",
    "config": "dict",
    "test_seeds": "list",
    "git": "dict?",
    "fit": "dict",
}
PROTOCOL_FIELDS = {"task": "str", "setting": "str", "method": "str"}
PROTOCOL_OPTIONAL = {
    "imagery": "str?",
    "steps": "int",
    "batch_size": "int",
    "lr": "number",
    "validation_every": "int",
    "validation_episodes": "int",
    "test_episodes": "int",
    "model": "dict",
    "imagery_changes": "dict",
    "trained_setting": "str",
    "fit_protocol_id": "str",
}
FIT_FIELDS = {"protocol_id": "str", "run_dir": "str", "checkpoint": "str"}
TEST_RECORD_FIELDS = {"split": "str"}
TEST_RECORD_OPTIONAL = {
    "checkpoint": "str?",
    "checkpoint_sha256": "str?",
    "global_step": "int?",
    "machine": "dict",
    "git": "dict?",
}
EPISODE_FIELDS = {"seed": "int", "success": "bool"}
EPISODE_OPTIONAL = {"outcome": "str", "error": "str?", "failure": "str?", "strict_success": "bool?"}


def _check_fields(
    record: Any, required: dict[str, str], optional: dict[str, str], where: str
) -> None:
    """CellFileError where `record` is no object, lacks a required key or holds a value of
    another kind than its field's."""
    if not isinstance(record, dict):
        raise CellFileError(f"{where} is {json.dumps(record)[:40]}, not an object")
    missing = [key for key in required if key not in record]
    if missing:
        raise CellFileError(f"{where} lacks {', '.join(missing)}")
    for key, kind in (required | optional).items():
        value = record.get(key)
        test, name = KINDS[kind.rstrip("?")]
        if key in record and not (test(value) or (value is None and kind.endswith("?"))):
            null = " or null" if kind.endswith("?") else ""
            raise CellFileError(f"{where}: {key} is {json.dumps(value)[:40]}, not {name}{null}")


def _check_interval(
    where: str, prefix: str, successes: int, episodes: int, record: dict[str, Any]
) -> None:
    """CellFileError where `<prefix>ci_low`/`<prefix>ci_high` are not the Wilson interval of the
    counts."""
    low, high = wilson_interval(successes, episodes)
    stored = record.get(f"{prefix}ci_low"), record.get(f"{prefix}ci_high")
    if not all(KINDS["number"][0](value) for value in stored) or not (
        math.isclose(stored[0], low, abs_tol=TOLERANCE)
        and math.isclose(stored[1], high, abs_tol=TOLERANCE)
    ):
        raise CellFileError(
            f"{where}: {prefix}ci_low-{prefix}ci_high {stored[0]}-{stored[1]} is not the "
            f"{CONFIDENCE:.0%} Wilson interval of {successes} of {episodes} ({low:.4f}-{high:.4f})"
        )


def _check_rate(where: str, key: str, rate: Any, successes: int, episodes: int) -> None:
    expected = successes / episodes if episodes else None
    if (rate is None) != (expected is None) or (
        rate is not None and not math.isclose(rate, expected, abs_tol=TOLERANCE)
    ):
        raise CellFileError(f"{where}: {key} {rate} is not {successes} of {episodes}")


def _check_counts(record: dict[str, Any], where: str) -> None:
    """Successes within episodes, the rate and the interval those counts give, the erred seeds
    as many as the errors; the same for the strict 6-DoF count where the record holds one."""
    episodes, successes, errors = record["episodes"], record["successes"], record.get("errors", 0)
    if episodes < 0 or errors < 0 or not 0 <= successes <= episodes:
        raise CellFileError(
            f"{where}: {successes} successes of {episodes} episodes ({errors} erred): counts lie "
            "in 0..episodes"
        )
    if record.get("confidence", CONFIDENCE) != CONFIDENCE:
        raise CellFileError(
            f"{where}: confidence {record['confidence']} is not {CONFIDENCE}, the confidence of "
            f"every interval the tables state ({CONFIDENCE:.0%} Wilson)"
        )
    _check_interval(where, "", successes, episodes, record)
    if "success_rate" in record:
        _check_rate(where, "success_rate", record["success_rate"], successes, episodes)
    erred_seeds = record.get("erred_seeds")
    if erred_seeds is not None and (
        len(erred_seeds) != errors or not all(KINDS["int"][0](seed) for seed in erred_seeds)
    ):
        raise CellFileError(f"{where}: erred_seeds {erred_seeds} are not the {errors} erred")
    strict = record.get("strict_successes")
    if strict is not None:
        if not 0 <= strict <= episodes:
            raise CellFileError(
                f"{where}: {strict} strict successes of {episodes} episodes: counts lie in "
                "0..episodes"
            )
        _check_interval(where, "strict_", strict, episodes, record)
        if "strict_success_rate" in record:
            rate = record["strict_success_rate"]
            _check_rate(where, "strict_success_rate", rate, strict, episodes)


def _listed(seeds: list[str]) -> str:
    """The first few of `seeds`, comma-separated."""
    return ", ".join(seeds[:5]) + (f" and {len(seeds) - 5} more" if len(seeds) > 5 else "")


def _check_seeds(seeds: Any, where: str) -> None:
    """CellFileError where `seeds` are no integers, repeat a seed (one episode counted twice) or
    hold a seed of no test episode (`splits.py`: a test seed is odd and below the validation
    seeds; an even one is a training seed)."""
    if not isinstance(seeds, list) or not all(_is_int(seed) for seed in seeds):
        raise CellFileError(f"{where} {json.dumps(seeds)[:40]} are not seeds (integers)")
    repeated = [str(seed) for seed, count in sorted(Counter(seeds).items()) if count > 1]
    if repeated:
        raise CellFileError(
            f"{where} list seed {_listed(repeated)} more than once: a test seed is one episode"
        )
    foreign = [
        f"{seed} ({'negative' if seed < 0 else split_of_seed(seed)})"
        for seed in seeds
        if seed < 0 or split_of_seed(seed) != "test"
    ]
    if foreign:
        raise CellFileError(
            f"{where} hold seeds of no test episode: {_listed(foreign)}; a test seed is odd and "
            f"below {VALIDATION_OFFSET}"
        )


def _check_episodes(record: dict[str, Any], where: str) -> None:
    """Its test seeds distinct seeds of the test split, as many as its episodes and erred ones;
    each episode record's types and its outcome agreeing with success and error; the counts of
    those that ran and erred those of the record, its test seeds and erred seeds theirs."""
    test_seeds = record.get("test_seeds")
    if test_seeds is not None:
        _check_seeds(test_seeds, f"{where}: its test_seeds")
        if len(test_seeds) != record["episodes"] + record.get("errors", 0):
            raise CellFileError(
                f"{where}: its {len(test_seeds)} test_seeds are not its {record['episodes']} "
                f"episodes and {record.get('errors', 0)} erred ones"
            )
    episodes = record.get("episode_results")
    if episodes is None:
        return
    for index, episode in enumerate(episodes):
        place = f"{where}: episode_results[{index}]"
        _check_fields(episode, EPISODE_FIELDS, EPISODE_OPTIONAL, place)
        erred = episode.get("error") is not None
        outcome = "error" if erred else ("success" if episode["success"] else "failure")
        if episode.get("outcome", outcome) != outcome:
            raise CellFileError(
                f"{place}: outcome {json.dumps(episode['outcome'])} is not {outcome} (success "
                f"{json.dumps(episode['success'])}, error {json.dumps(episode.get('error'))}; "
                f"outcomes: {', '.join(OUTCOMES)})"
            )
    ran = [episode for episode in episodes if episode.get("error") is None]
    counts = {
        "episodes": len(ran),
        "successes": sum(episode["success"] for episode in ran),
        "errors": len(episodes) - len(ran),
    }
    if record.get("strict_successes") is not None:
        counts["strict_successes"] = sum(episode.get("strict_success") is True for episode in ran)
    for key, count in counts.items():
        if record.get(key, 0) != count:
            raise CellFileError(
                f"{where}: {key} is {record.get(key, 0)}, its episodes hold {count}"
            )
    seeds = [episode["seed"] for episode in episodes]
    _check_seeds(seeds, f"{where}: its episode_results")
    if record.get("test_seeds", seeds) != seeds:
        raise CellFileError(f"{where}: test_seeds are not the seeds of its episode_results")
    erred = sorted(episode["seed"] for episode in episodes if episode.get("error") is not None)
    if sorted(record.get("erred_seeds", erred)) != erred:
        raise CellFileError(
            f"{where}: erred_seeds {record['erred_seeds']} are not the seeds of its erred "
            f"episodes {erred}"
        )


def _check_cell(record: dict[str, Any], where: str) -> None:
    """A cell's own fields: its protocol naming the cell's task, setting, method and imagery, the
    chosen checkpoint's step, the validation rounds, machines and overlays."""
    _check_fields(record, CELL_FIELDS, CELL_OPTIONAL, where)
    protocol = record["protocol"]
    _check_fields(protocol, PROTOCOL_FIELDS, PROTOCOL_OPTIONAL, f"{where}: protocol")
    _check_names(protocol, f"{where}: protocol")
    for key in ("task", "setting", "method", "imagery"):
        if protocol.get(key) != record.get(key):
            raise CellFileError(
                f"{where}: its protocol's {key} is {json.dumps(protocol.get(key))}, the cell's "
                f"{json.dumps(record.get(key))}"
            )
    _check_fields(record["checkpoint"], {"step": "int"}, {"path": "str"}, f"{where}: checkpoint")
    for index, entry in enumerate(record.get("validation", [])):
        _check_round(entry, protocol.get("validation_episodes"), f"{where}: validation[{index}]")
    if not all(isinstance(overlay, str) for overlay in record.get("overlays", [])):
        raise CellFileError(f"{where}: overlays {record['overlays']} are not config paths")
    _check_fit(record, where)


def _check_machine(record: dict[str, Any], where: str) -> None:
    """The machines a cell or test record names: those its checkpoint was fitted on (`fit`, a
    list) and the one that tested it (`test`)."""
    machine = record.get("machine", {})
    _check_fields(machine, {}, {"fit": "list", "test": "dict"}, f"{where}: machine")
    for index, fit in enumerate(machine.get("fit", [])):
        _check_fields(fit, {}, {"cpu": "str?", "gpu": "str?"}, f"{where}: machine.fit[{index}]")


def _check_round(entry: Any, episodes: int | None, where: str) -> None:
    """A validation round: its step, its success rate (null: the round erred) a fraction of the
    protocol's `episodes` a round (where it names them), and mira's view-search figures, if any."""
    view_search = dict.fromkeys(VIEW_SEARCH_FIGURES, "number")  # mira's, rounds kept since
    _check_fields(entry, {"step": "int", "success_rate": "number?"}, view_search, where)
    rate = entry["success_rate"]
    if rate is None:
        return
    successes = rate * episodes if episodes else rate
    if not 0 <= rate <= 1 or (episodes and not math.isclose(successes, round(successes))):
        of = f" of {episodes} episodes" if episodes else ""
        raise CellFileError(f"{where}: success_rate {rate} is no success rate{of}")


def _check_names(record: dict[str, Any], where: str) -> None:
    """CellFileError where a record or protocol names a task, setting, method or imagery this
    package does not have (the table would show it as a column or row of its own)."""
    known = {
        "task": tuple(TASKS),
        "setting": SETTINGS,
        "trained_setting": SETTINGS,
        "method": METHOD_NAMES,
        "imagery": (None, *IMAGERY_KINDS),
    }
    for key, names in known.items():
        if key in record and record[key] not in names:
            raise CellFileError(
                f"{where}: {key} {json.dumps(record[key])[:40]} is none of this package's "
                f"({', '.join(str(name) for name in names)})"
            )


def _check_fit(record: dict[str, Any], where: str) -> None:
    """A cross-setting cell naming its fit (see the module docstring); a cell of one setting
    naming none."""
    protocol = record["protocol"]
    cross = [key for key in CROSS_KEYS if key in protocol]
    if not cross:
        if "fit" in record:
            raise CellFileError(f"{where} names a fit, but its protocol has no trained_setting")
        return
    if len(cross) < len(CROSS_KEYS) or "fit" not in record:
        raise CellFileError(
            f"{where}: a cell tested on another setting than it was trained on needs "
            f"{', '.join(CROSS_KEYS)} in its protocol and its fit"
        )
    if protocol["trained_setting"] == protocol["setting"]:
        raise CellFileError(
            f"{where}: trained_setting {protocol['setting']} is the setting it was tested in"
        )
    expected = protocol_id(fit_protocol(protocol))
    if protocol["fit_protocol_id"] != expected:
        raise CellFileError(
            f"{where}: fit_protocol_id {protocol['fit_protocol_id']} is not the id of the protocol "
            f"it names with trained_setting {protocol['trained_setting']} ({expected})"
        )
    fit = record["fit"]
    _check_fields(fit, FIT_FIELDS, {}, f"{where}: fit")
    if fit["protocol_id"] != expected:
        raise CellFileError(
            f"{where}: its fit's protocol_id {fit['protocol_id']} is not its protocol's "
            f"fit_protocol_id {expected}"
        )
    if fit["checkpoint"] != record["checkpoint"].get("path"):
        raise CellFileError(
            f"{where}: its fit's checkpoint {fit['checkpoint']} is not the checkpoint it tested "
            f"({record['checkpoint'].get('path')})"
        )


def _check_world(record: dict[str, Any], where: str, world: str, archived: bool) -> None:
    """CellFileError naming both fingerprints where `record` was measured in another world (in a
    component it read: `sim/fingerprint.py`)."""
    measured = record["world"]
    if same_world(measured, world, components_read(record.get("imagery"))):
        return
    git = record.get("git")
    commit = git.get("commit") if isinstance(git, dict) else None
    at = f" at commit {commit}" if commit else ""
    if archived:
        raise CellFileError(
            f"{where} lies in the archive of world {world} but was measured in world "
            f"{measured}{at}: move it to the archive of its own world, {ARCHIVE}/world-{measured}/"
        )
    raise CellFileError(
        f"{where} was measured in world {measured}{at}, this checkout's world is {world}: its "
        f"seeds build other scenes here. Keep it under <results>/{ARCHIVE}/world-{measured}/ "
        "(report shows it under its own heading) or measure it again"
    )


def _archived(path: Path, pattern: re.Pattern) -> str | None:
    names = [
        match.group(1)
        for parent, name in pairwise(path.absolute().parts)
        if parent == ARCHIVE and (match := pattern.fullmatch(name))
    ]
    return names[-1] if names else None


def archived_world(path: Path) -> str | None:
    """The fingerprint of the archive `path` lies in (`.../archive/world-<fingerprint>/...`)."""
    return _archived(path, ARCHIVED_WORLD)


def archived_recipe(path: Path) -> str | None:
    """The name of the earlier recipe whose archive `path` lies in (`.../archive/recipe-<name>/`)."""
    return _archived(path, ARCHIVED_RECIPE)


def _read(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as error:  # ValueError: not JSON, or an integer of 4300+ digits
        raise CellFileError(f"unreadable results file {path}: {error}") from error
    except RecursionError as error:
        raise CellFileError(f"unreadable results file {path}: nested too deeply") from error


def _checked(record: Any, path: Path, world: str | None) -> dict[str, Any]:
    """`record` read from `path`, checked (see the module docstring), with "path" added."""
    where = str(path)
    _check_fields(record, RECORD_FIELDS, RECORD_OPTIONAL, where)
    _check_names(record, where)
    if record.get("split", "test") != "test":
        raise CellFileError(
            f"{where} is neither a run-cell cell nor a test record: its split is "
            f"{json.dumps(record['split'])}"
        )
    archive = archived_world(path)
    _check_world(record, where, world or archive or world_fingerprint(), archive is not None)
    if "protocol" in record:
        _check_cell(record, where)
    else:
        _check_fields(record, TEST_RECORD_FIELDS, TEST_RECORD_OPTIONAL, where)
    _check_machine(record, where)
    _check_counts(record, where)
    _check_episodes(record, where)
    return record | {"path": where}


def load_record(path: Path, world: str | None = None) -> dict[str, Any]:
    """The cell or test record in `path`, checked, with its path under "path"; measured in
    `world` (default: the world of the archive it lies in, else this checkout's)."""
    return _checked(_read(path), path, world)


def load_cell(path: Path, world: str | None = None) -> dict[str, Any]:
    """The run-cell cell in `path`, as `load_record` checks it."""
    record = _read(path)
    if isinstance(record, dict) and "protocol" not in record:
        raise CellFileError(f"{path} is not a cell of run-cell (no protocol)")
    return _checked(record, path, world)


def _placed(record: dict[str, Any], path: Path, archived: bool) -> dict[str, Any]:
    """`record` where it lies where run-cell writes its cell (`<column>/<row>.json`); in an
    archived world also a cell trained and tested in one setting under `<task>-<setting>`, as
    run-cell wrote it before a column was named by its training setting too."""
    task, setting, trained = record["task"], record["setting"], trained_setting(record)
    column = column_folder(task, setting, trained)
    row = row_key(record["method"], record.get("imagery"))
    folders = (
        {column, column_folder(task, setting)} if archived and trained == setting else {column}
    )
    if path.parent.name not in folders or path.stem != row:
        raise CellFileError(
            f"{path} holds the cell {column}/{row}.json: a cell is read only where run-cell "
            "writes it"
        )
    return record


@dataclass
class Archive:
    """The cells of an earlier world, kept under `<results>/archive/world-<world>/`, or, where
    `recipe` names one, this world's cells measured under an earlier training recipe, kept under
    `<results>/archive/recipe-<recipe>/` (`world` is then this checkout's)."""

    world: str
    folder: Path
    cells: list[dict[str, Any]] = field(default_factory=list)
    recipe: str | None = None


@dataclass
class Found:
    """What `find_records` found: the records of this checkout's world, the archived worlds, and
    the test records left out (under a folder of cells: not cells of the table)."""

    records: list[dict[str, Any]] = field(default_factory=list)
    archives: list[Archive] = field(default_factory=list)
    left_out: list[Path] = field(default_factory=list)


def _folders(root: Path) -> list[tuple[Path, str | None, str | None]]:
    """(folder, archived world, earlier recipe) of each folder `root` stands for: None and None
    for this checkout's table."""
    if root.absolute().name == ARCHIVE:
        children = sorted(path for path in root.iterdir() if path.is_dir())
        return [
            (path, world, recipe)
            for path in children
            for world, recipe in [(archived_world(path), archived_recipe(path))]
            if world is not None or recipe is not None
        ]
    world, recipe = archived_world(root), archived_recipe(root)
    if world is not None:
        return [(root, world, None)]
    if recipe is not None:
        return [(root, None, recipe)]
    return [(root, None, None)] + (_folders(root / ARCHIVE) if (root / ARCHIVE).is_dir() else [])


def find_records(roots: list[Path]) -> Found:
    """The cells and test records under `roots`, checked (see the module docstring)."""
    found, archives, seen = Found(), {}, set()
    for root in roots:
        if not root.is_dir():
            raise FileNotFoundError(f"no such directory: {root}")
        for folder, world, recipe in _folders(root):
            if folder.resolve() in seen:
                continue
            seen.add(folder.resolve())
            archived = world is not None or recipe is not None
            cells = sorted(
                path
                for path in folder.glob("*/*.json")
                if path.parent.name != ARCHIVE and not fnmatch.fnmatch(path.name, TEST_RECORD_GLOB)
            )
            tests = sorted(
                path
                for path in folder.rglob(TEST_RECORD_GLOB)
                if archived or not path.is_relative_to(folder / ARCHIVE)
            )
            if cells or archived:
                records = [
                    _placed(load_cell(path, world), path, world is not None) for path in cells
                ]
                found.left_out += tests
            else:
                records = [load_record(path) for path in tests]
            if not archived:
                found.records += records
            elif records:
                archive = Archive(world or world_fingerprint(), folder, recipe=recipe)
                archives.setdefault((world, recipe), archive).cells.extend(records)
    found.archives = list(archives.values())
    return found
