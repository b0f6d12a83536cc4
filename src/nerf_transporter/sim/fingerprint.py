"""The world fingerprint: a hash of the code and constants that decide what an episode contains.

An episode is a function of its seed *and* of the world that played it: task assets (sizes,
clearances, colours), camera rigs, the robot, the simulation constants, the geometry conventions
and the on-disk format. Data and cached imagery carry this fingerprint, so a changed world is never
mixed with episodes of the old one.

It is computed from the source text of the world's modules (read as files, never imported, so it
works on a training machine without PyBullet), with comments, docstrings and blank lines removed:
editing prose does not change it, editing a constant or a line of code does. Every module has its
own digest, so a mismatch can say which module changed.
"""

from __future__ import annotations

import ast
import hashlib
import io
import re
import tokenize
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
# Relative to the package root; a pattern with * takes every matching module.
WORLD_MODULES = (
    "geometry.py",
    "sim/assets.py",
    "sim/cameras.py",
    "sim/env.py",
    "sim/primitives.py",
    "sim/robot.py",
    "sim/shapes.py",
    "sim/tasks/*.py",
)
# Bumped when what generation writes changes without any world module changing.
GENERATOR_FORMAT = 2


def _docstring_lines(tree: ast.AST) -> set[int]:
    """1-based line numbers of module, class and function docstrings."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if (
                body
                and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)
            ):
                lines.update(range(body[0].lineno, (body[0].end_lineno or body[0].lineno) + 1))
    return lines


def normalized_source(source: str) -> str:
    """Python source without comments, docstrings, blank lines and runs of whitespace."""
    lines = source.splitlines()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            row, col = token.start
            lines[row - 1] = lines[row - 1][:col]
    skip = _docstring_lines(ast.parse(source))
    kept = (
        re.sub(r"\s+", " ", line).strip()
        for number, line in enumerate(lines, start=1)
        if number not in skip
    )
    return "\n".join(line for line in kept if line)


def module_digests(root: Path = PACKAGE_ROOT) -> dict[str, str]:
    """Module path (relative to the package) -> short digest of its normalised source."""
    digests = {}
    for pattern in WORLD_MODULES:
        paths = sorted(root.glob(pattern))
        if not paths:
            raise FileNotFoundError(f"world module {pattern} not found under {root}")
        for path in paths:
            text = normalized_source(path.read_text(encoding="utf-8"))
            digests[path.relative_to(root).as_posix()] = hashlib.sha256(text.encode()).hexdigest()[
                :12
            ]
    return digests


def world_description(root: Path = PACKAGE_ROOT) -> dict:
    """{"fingerprint": ..., "format": ..., "modules": {path: digest}}, as stored with data."""
    modules = module_digests(root)
    text = f"format {GENERATOR_FORMAT}\n" + "\n".join(
        f"{k} {v}" for k, v in sorted(modules.items())
    )
    return {
        "fingerprint": hashlib.sha256(text.encode()).hexdigest()[:16],
        "format": GENERATOR_FORMAT,
        "modules": modules,
    }


_CACHED: dict | None = None


def world() -> dict:
    """`world_description()` of the installed package, computed once per process."""
    global _CACHED
    if _CACHED is None:
        _CACHED = world_description()
    return _CACHED


def world_fingerprint() -> str:
    """The 16-hex-digit fingerprint of the installed package's world."""
    return world()["fingerprint"]


def world_changes(stored: dict, current: dict) -> list[str]:
    """What differs between two `world_description()`s, one line per module or field."""
    changes = []
    if stored.get("format") != current.get("format"):
        changes.append(f"generator format {stored.get('format')} -> {current.get('format')}")
    old, new = stored.get("modules", {}), current.get("modules", {})
    for name in sorted(set(old) | set(new)):
        if name not in old:
            changes.append(f"{name} added")
        elif name not in new:
            changes.append(f"{name} removed")
        elif old[name] != new[name]:
            changes.append(f"{name} changed")
    if not changes and stored.get("fingerprint") != current.get("fingerprint"):
        changes.append(f"fingerprint {stored.get('fingerprint')} -> {current.get('fingerprint')}")
    return changes
