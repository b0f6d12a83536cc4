"""Config files that compose: a top-level `__include__` names the files a config builds on.

`lightning fit --config configs/block_insertion.yaml` reads `configs/common/base.yaml` through the
task file's `__include__: common/base.yaml`, then the task file's own keys over it. jsonargparse 4
applies a `config:` key inside a config file, but the including file's `model:` or `data:` then
replaces the included one instead of adding to it; its v5 brings an `__include__` key that merges.
Until then this parser mode (`PARSER_MODE`, YAML with OmegaConf's `${...}` interpolation as
jsonargparse's "omegaconf" mode) resolves the key while loading: the files it names (a path or a
list of paths, relative to the including file, themselves able to include) are merged in order,
then the file's own keys over them. Mappings merge key by key; lists and other values replace.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml
from jsonargparse import get_loader, set_loader
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

INCLUDE_KEY = "__include__"
PARSER_MODE = "omegaconf_include"


class ConfigIncludeError(ValueError):
    """An `__include__` that is not a path or a list of paths, or that includes itself."""


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """`over` on top of `base`: mappings merge key by key, any other value replaces."""
    merged = dict(base)
    for key, value in over.items():
        below = merged.get(key)
        both_mappings = isinstance(value, dict) and isinstance(below, dict)
        merged[key] = merge(below, value) if both_mappings else value
    return merged


def load_yaml(text: str) -> Any:
    """A YAML value with OmegaConf's `${...}` interpolation resolved."""
    value = get_loader("yaml")(text)
    if isinstance(value, dict | list):
        return OmegaConf.to_container(OmegaConf.create(value), resolve=True)
    return value


def load_with_includes(text: str, folder: Path, chain: tuple[Path, ...] = ()) -> Any:
    """The YAML `text` of a config in `folder`, its `__include__` resolved (see the module doc)."""
    value = load_yaml(text)
    if not isinstance(value, dict) or INCLUDE_KEY not in value:
        return value
    names = value.pop(INCLUDE_KEY)
    names = [names] if isinstance(names, str) else names
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise ConfigIncludeError(f"{INCLUDE_KEY} takes a path or a list of paths, got {names!r}")
    merged: dict[str, Any] = {}
    for name in names:
        path = (folder / name).resolve()
        if path in chain:
            loop = " -> ".join(str(p) for p in (*chain, path))
            raise ConfigIncludeError(f"{INCLUDE_KEY} loop: {loop}")
        included = load_with_includes(path.read_text(), path.parent, (*chain, path))
        if not isinstance(included, dict):
            raise ConfigIncludeError(f"{INCLUDE_KEY}: {path} does not hold a mapping of keys")
        merged = merge(merged, included)
    return merge(merged, value)


def load_config(text: str) -> Any:
    """jsonargparse loader of `PARSER_MODE`. jsonargparse 4 reads a config file with the file's
    folder as the working directory, so a relative `__include__` is relative to that file."""
    return load_with_includes(text, Path(os.getcwd()))


def register() -> str:
    """Make `PARSER_MODE` known to jsonargparse; returns its name for `parser_mode`."""
    exceptions = (yaml.YAMLError, OmegaConfBaseException, OSError, ConfigIncludeError)
    set_loader(PARSER_MODE, load_config, exceptions)
    return PARSER_MODE
