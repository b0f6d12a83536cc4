"""On-disk cache of evaluation imagery, keyed by task, setting, seed and a hash of the imagery config.

Re-evaluating a checkpoint then reuses the imagery of every seed instead of refitting its NeRF.
Files are npz (no pickle) written to a temporary name and renamed, so an interrupted write never
leaves a half file behind; a file damaged afterwards is deleted with a warning and rebuilt.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from nerf_transporter.atomic import write_file

IMAGERY_KEYS = ("colour", "height", "views")
log = logging.getLogger(__name__)


def config_hash(config: dict) -> str:
    """Short, stable hash of a JSON-serialisable config."""
    text = json.dumps(config, sort_keys=True, default=_json_default)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _json_default(value: object) -> object:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot hash a config value of type {type(value).__name__}: {value!r}")


class ImageryCache:
    """Imagery (colour, height, views) per episode under `root/<task>-<setting>/<seed>-<hash>.npz`."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)

    def path(self, task: str, setting: str, seed: int, key: str) -> Path:
        return self.root / f"{task}-{setting}" / f"{seed}-{key}.npz"

    def load(self, task: str, setting: str, seed: int, key: str) -> dict[str, np.ndarray] | None:
        """The cached imagery, or None when absent or corrupt (a corrupt file is deleted, with a
        warning, so that the caller rebuilds it)."""
        path = self.path(task, setting, seed, key)
        if not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                missing = [name for name in IMAGERY_KEYS if name not in data.files]
                if missing:
                    raise ValueError(f"missing arrays {missing}")
                return {name: data[name] for name in IMAGERY_KEYS}
        except (zipfile.BadZipFile, zlib.error, EOFError, ValueError) as error:
            log.warning("corrupt imagery cache file %s (%s): deleted, rebuilding it", path, error)
            path.unlink(missing_ok=True)
            return None

    def save(
        self, task: str, setting: str, seed: int, key: str, imagery: dict[str, np.ndarray]
    ) -> Path:
        arrays = {name: imagery[name] for name in IMAGERY_KEYS}
        return write_file(
            self.path(task, setting, seed, key),
            lambda file: np.savez_compressed(file, **arrays),
        )
