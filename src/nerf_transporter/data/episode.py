"""On-disk format of a demonstration dataset (DESIGN section 9).

    <dataset>/
      dataset.json            generation config; appending with a different config is refused
      failed/<seed>.json      seeds whose oracle rollout failed (never retried)
      000003-6/               <index>-<seed>: index of the seed in its split (splits.split_seed)
        meta.json             seed, task, oracle action, state, timings, sha256 of every npz
        nerf_views.npz        (optional) N RGB images + intrinsics + camera-to-world poses
        rgbd.npz              the three RGB-D captures
        imagery.npz           V views: colour uint8, height float16, view angles

Episodes are written into a hidden temporary directory and renamed into place, so a directory with
a valid name is always complete; meta.json holds checksums so `verify_episode` can name any file
that was damaged afterwards. Everything is JSON or `.npz` read with `allow_pickle=False`.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import socket
import zipfile
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

FORMAT_VERSION = 1
META_FILE = "meta.json"
DATASET_FILE = "dataset.json"
FAILED_DIR = "failed"
TEMP_PREFIX = ".tmp-"
EPISODE_NAME = re.compile(r"^(\d{6})-(\d+)$")


class CorruptEpisodeError(RuntimeError):
    """An episode directory whose files are missing, truncated or do not match their checksums."""


class DatasetConfigMismatchError(ValueError):
    """A dataset directory that holds episodes generated with a different configuration."""


@dataclass(frozen=True)
class EpisodeRef:
    index: int
    seed: int
    path: Path


@dataclass
class Episode:
    path: Path
    meta: dict[str, Any]
    arrays: dict[str, dict[str, np.ndarray]]  # npz name without extension -> arrays

    @property
    def name(self) -> str:
        return self.path.name


def episode_dirname(index: int, seed: int) -> str:
    return f"{index:06d}-{seed}"


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _write_json(path: Path, payload: Mapping[str, Any]) -> None:
    """Write JSON atomically (temporary file in the same directory, then rename)."""
    temp = path.with_name(f"{TEMP_PREFIX}{path.name}-{socket.gethostname()}-{os.getpid()}")
    temp.write_text(json.dumps(payload, indent=2, sort_keys=True) + "\n")
    os.replace(temp, path)


def _temp_dir_name(final_name: str) -> str:
    return f"{TEMP_PREFIX}{final_name}-{socket.gethostname()}-{os.getpid()}"


def write_episode(
    dataset_dir: str | os.PathLike,
    index: int,
    seed: int,
    meta: Mapping[str, Any],
    arrays: Mapping[str, Mapping[str, np.ndarray]],
) -> Path:
    """Write one episode atomically and return its directory.

    `arrays` maps a file stem ("rgbd", "imagery", ...) to the arrays stored in `<stem>.npz`. If the
    episode already exists (another worker finished it first) the existing one is kept.
    """
    dataset_dir = Path(dataset_dir)
    final = dataset_dir / episode_dirname(index, seed)
    temp = dataset_dir / _temp_dir_name(final.name)
    if temp.exists():
        shutil.rmtree(temp)
    temp.mkdir(parents=True)
    try:
        files = {}
        for stem, content in arrays.items():
            for key, value in content.items():
                if np.asarray(value).dtype == object:
                    raise TypeError(f"{stem}.npz: array {key!r} has dtype object (no pickle)")
            path = temp / f"{stem}.npz"
            np.savez_compressed(path, **{k: np.asarray(v) for k, v in content.items()})
            files[path.name] = {"sha256": _sha256(path), "bytes": path.stat().st_size}
        full_meta = {**meta, "format": FORMAT_VERSION, "index": index, "seed": seed, "files": files}
        (temp / META_FILE).write_text(json.dumps(full_meta, indent=2, sort_keys=True) + "\n")
        if final.exists():
            shutil.rmtree(temp)
            return final
        os.rename(temp, final)
    except BaseException:
        shutil.rmtree(temp, ignore_errors=True)
        raise
    return final


def list_episodes(dataset_dir: str | os.PathLike) -> list[EpisodeRef]:
    """Complete episodes of a dataset, sorted by index (temporary directories are ignored)."""
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        return []
    refs = []
    for child in dataset_dir.iterdir():
        match = EPISODE_NAME.match(child.name)
        if match and child.is_dir():
            refs.append(EpisodeRef(int(match.group(1)), int(match.group(2)), child))
    return sorted(refs, key=lambda ref: ref.index)


def stale_temp_dirs(dataset_dir: str | os.PathLike) -> list[Path]:
    """Temporary episode directories left behind by interrupted writes."""
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        return []
    return sorted(p for p in dataset_dir.iterdir() if p.name.startswith(TEMP_PREFIX))


def remove_stale_temp_dirs(dataset_dir: str | os.PathLike) -> list[Path]:
    """Delete temporary directories of this host whose writing process is gone; return them."""
    host = socket.gethostname()
    removed = []
    for path in stale_temp_dirs(dataset_dir):
        prefix, _, pid = path.name.rpartition("-")
        if not prefix.endswith(f"-{host}") or not pid.isdigit():
            continue
        if int(pid) != os.getpid() and _process_alive(int(pid)):
            continue
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
        removed.append(path)
    return removed


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def read_meta(path: str | os.PathLike) -> dict[str, Any]:
    """meta.json of an episode directory, with a clear error when it is missing or unreadable."""
    path = Path(path)
    try:
        return json.loads((path / META_FILE).read_text())
    except FileNotFoundError as exc:
        raise CorruptEpisodeError(f"episode {path.name}: {META_FILE} is missing ({path})") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CorruptEpisodeError(f"episode {path.name}: {META_FILE} is corrupt ({exc})") from exc


def _load_npz(episode_path: Path, file_name: str) -> dict[str, np.ndarray]:
    path = episode_path / file_name
    try:
        with np.load(path, allow_pickle=False) as npz:
            return {key: npz[key] for key in npz.files}
    except FileNotFoundError as exc:
        raise CorruptEpisodeError(
            f"episode {episode_path.name}: {file_name} is missing ({path})"
        ) from exc
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as exc:
        raise CorruptEpisodeError(
            f"episode {episode_path.name}: {file_name} is corrupt or truncated ({exc}); "
            f"delete {episode_path} and re-run generation"
        ) from exc


def load_episode(path: str | os.PathLike, files: Iterable[str] | None = None) -> Episode:
    """Load meta.json and the npz files named in `files` (stems; all stored files when None)."""
    path = Path(path)
    meta = read_meta(path)
    stored = [name.removesuffix(".npz") for name in meta.get("files", {})]
    wanted = stored if files is None else list(files)
    arrays = {}
    for stem in wanted:
        if stem not in stored:
            raise CorruptEpisodeError(
                f"episode {path.name}: {stem}.npz is not part of this episode (stored: "
                f"{', '.join(s + '.npz' for s in stored) or 'none'})"
            )
        arrays[stem] = _load_npz(path, f"{stem}.npz")
    return Episode(path, meta, arrays)


def verify_episode(path: str | os.PathLike) -> None:
    """Check meta.json, the size and checksum of every listed file, and that every array loads."""
    path = Path(path)
    meta = read_meta(path)
    if meta.get("format") != FORMAT_VERSION:
        raise CorruptEpisodeError(
            f"episode {path.name}: format {meta.get('format')!r}, expected {FORMAT_VERSION}"
        )
    for name, expected in meta.get("files", {}).items():
        file_path = path / name
        if not file_path.is_file():
            raise CorruptEpisodeError(f"episode {path.name}: {name} is missing ({file_path})")
        size = file_path.stat().st_size
        if size != expected["bytes"]:
            raise CorruptEpisodeError(
                f"episode {path.name}: {name} is truncated or altered "
                f"({size} bytes, expected {expected['bytes']})"
            )
        if _sha256(file_path) != expected["sha256"]:
            raise CorruptEpisodeError(f"episode {path.name}: {name} does not match its checksum")
        _load_npz(path, name)


# ---------------------------------------------------------------------------------------------
# Failed seeds and the dataset config
# ---------------------------------------------------------------------------------------------


def record_failure(dataset_dir: str | os.PathLike, seed: int, reason: str) -> None:
    failed = Path(dataset_dir) / FAILED_DIR
    failed.mkdir(parents=True, exist_ok=True)
    _write_json(failed / f"{seed}.json", {"seed": seed, "reason": reason})


def failed_seeds(dataset_dir: str | os.PathLike) -> dict[int, str]:
    """Seeds whose oracle rollout failed -> reason."""
    failed = Path(dataset_dir) / FAILED_DIR
    if not failed.is_dir():
        return {}
    result = {}
    for path in failed.glob("*.json"):
        if path.stem.isdigit():
            result[int(path.stem)] = json.loads(path.read_text()).get("reason", "")
    return result


def _differences(stored: Any, requested: Any, prefix: str = "") -> list[str]:
    if isinstance(stored, dict) and isinstance(requested, dict):
        lines = []
        for key in sorted(set(stored) | set(requested)):
            name = f"{prefix}.{key}" if prefix else key
            if key not in stored:
                lines.append(f"{name}: not in the stored config, requested {requested[key]!r}")
            elif key not in requested:
                lines.append(f"{name}: stored {stored[key]!r}, not in the requested config")
            else:
                lines.extend(_differences(stored[key], requested[key], name))
        return lines
    if isinstance(stored, float | int) and isinstance(requested, float | int):
        same = np.isclose(stored, requested, rtol=1e-9, atol=0.0)
    elif isinstance(stored, list) and isinstance(requested, list):
        same = len(stored) == len(requested) and not _differences(
            dict(enumerate(stored)), dict(enumerate(requested))
        )
    else:
        same = stored == requested
    return [] if same else [f"{prefix}: stored {stored!r}, requested {requested!r}"]


def read_dataset_config(dataset_dir: str | os.PathLike) -> dict[str, Any] | None:
    path = Path(dataset_dir) / DATASET_FILE
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetConfigMismatchError(f"{path} is corrupt ({exc})") from exc


def check_dataset_config(dataset_dir: str | os.PathLike, config: Mapping[str, Any]) -> bool:
    """True if dataset.json exists and equals `config`, False if there is none; raises
    DatasetConfigMismatchError naming every difference otherwise."""
    dataset_dir = Path(dataset_dir)
    stored = read_dataset_config(dataset_dir)
    if stored is None:
        return False
    differences = _differences(stored, json.loads(json.dumps(config)))
    if differences:
        raise DatasetConfigMismatchError(
            f"{dataset_dir} was generated with a different configuration; refusing to mix "
            "episodes. Differences:\n  "
            + "\n  ".join(differences)
            + "\nUse another --data-dir, or delete the dataset to regenerate it."
        )
    return True


def ensure_dataset_config(dataset_dir: str | os.PathLike, config: Mapping[str, Any]) -> None:
    """Create dataset.json, or check that the stored one equals `config` (refusal names the keys)."""
    if not check_dataset_config(dataset_dir, config):
        Path(dataset_dir).mkdir(parents=True, exist_ok=True)
        _write_json(Path(dataset_dir) / DATASET_FILE, json.loads(json.dumps(config)))
