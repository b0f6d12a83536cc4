"""Atomic file writes: the content goes to a temporary file in the target's folder, which is then
renamed over the target (`os.replace`) or, where nothing may be replaced, linked to its name
(`os.link`, which fails if the name exists). A reader sees the old file or the whole new one, and an
interrupted write leaves no half file under the target's name."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# files get the mode a plain `open` would give them (mkstemp's temporary files are private: 0600)
FILE_MODE = 0o666 & ~_umask()


def write_file(
    path: str | os.PathLike, write: Callable[[IO[bytes]], object], *, overwrite: bool = True
) -> Path:
    """Write `path` atomically with `write(file)` (a binary file). With `overwrite=False` the name
    is claimed atomically too: FileExistsError when `path` exists, even if another process wrote
    it a moment ago."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}-", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as file:
            write(file)
        os.chmod(temporary, FILE_MODE)
        if overwrite:
            os.replace(temporary, path)
        else:
            os.link(temporary, path)
    finally:
        Path(temporary).unlink(missing_ok=True)
    return path


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = True) -> Path:
    """Write `text` (UTF-8) to `path` atomically (see `write_file`)."""
    return write_file(path, lambda file: file.write(text.encode()), overwrite=overwrite)


def write_json(
    path: str | os.PathLike, payload: Any, *, overwrite: bool = True, sort_keys: bool = False
) -> Path:
    """Write `payload` as indented JSON with a final newline to `path` atomically (see
    `write_file`)."""
    text = json.dumps(payload, indent=2, sort_keys=sort_keys) + "\n"
    return write_text(path, text, overwrite=overwrite)


def write_new_json(directory: str | os.PathLike, stem: str, payload: Any) -> Path:
    """Write `<stem>.json` in `directory`, or `<stem>-2.json`, `-3`, ... if taken: never replaces."""
    number = 1
    while True:
        name = f"{stem}.json" if number == 1 else f"{stem}-{number}.json"
        try:
            return write_json(Path(directory) / name, payload, overwrite=False)
        except FileExistsError:
            number += 1


def unwritable_reason(folder: str | os.PathLike) -> str | None:
    """Why no file can be written into `folder` (created as needed), None where one can: its
    nearest existing ancestor must be a folder a file can be created in (probed with one)."""
    existing = Path(folder).absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        return f"{existing} is not a folder"
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        return f"no file can be created in {existing} ({error.strerror or error})"
    return None


class UnwritableError(ValueError):
    """An output a command was asked to write cannot be written: found before any work is spent."""


def check_writable(what: str, path: str | os.PathLike, *, file: bool = False) -> None:
    """UnwritableError naming `what` (the option or the output) and `path` where no file can be
    written into the folder `path` (with `file`: written as the file `path`), before any work is
    spent on what goes there (`unwritable_reason`)."""
    path = Path(path)
    if file and path.is_dir():
        raise UnwritableError(f"{what} {path} is a folder, not a file name")
    if reason := unwritable_reason(path.parent if file else path):
        raise UnwritableError(f"{what} {path} cannot be written: {reason}")
