"""The world fingerprint: what decides an episode, component by component.

An episode is a function of its seed *and* of the world that played it. The world comes apart into
`COMPONENTS`, each with its own digest:

- `physics`: physics and tasks: the robot, the assets, the tasks, the simulation and the workspace;
- `rgbd`: the RGB-D rig (what the heightmap methods read);
- `nerf`: the NeRF rig (whose images the radiance fields are fitted to);
- `imagery`: the imagery settings: the view grid and the orthographic views rendered over it.

A component's digest hashes its constants and its part of the committed trace. The constants are
read from the source of the world modules (`WORLD_MODULES`, as files, never imported: no simulator
is needed) as the text of every module-level and class-level assignment (`CLEARANCE = 0.009`),
whatever the formatting; functions, comments and docstrings are not read, so extracting a helper,
renaming a local variable or rewording a docstring changes nothing (what a function computes, a
constant built by a call included, shows in the trace). The trace
(`sim/world_trace.json`, written by `python -m nerf_transporter.sim.trace --write`, which a test
plays again) records what the simulator does on fixed seeds: the scenes after reset, the oracle's
action, the scenes settled after it, the assets built, and what each rig sees of a fixed scene.

The world's fingerprint hashes the component digests and the generator's format. Every world the
package has had is recorded in `sim/worlds.json` (fingerprint -> component digests), so a stored
fingerprint can be taken apart: a record is of this world where the components it read are this
world's (`same_world`, `components_read`): a changed NeRF rig leaves the heightmap methods' cells
and the state method's valid. A world recorded there keeps the fingerprint it is recorded under:
`2b2aee17dfd72f31`, the fingerprint the source-hash scheme gave the world the trace was first
written in, names that world still, so the cells, datasets and policies made in it stay its own.

A trace played again may also differ from the committed one by float noise alone: the same
constants, the same assets and outcomes, numbers moved in the last bits and amplified by an
episode's contacts (the world's arithmetic made the same on every CPU did this once). Such a trace
is written with `python -m nerf_transporter.sim.trace --write --same-world REASON`, which records
in `sim/worlds.json` that the digest it gives a component is the committed one's
(`same_within_float_noise`, with the reason), so the world keeps its name and components.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from nerf_transporter.atomic import write_json
from nerf_transporter.console import HelpFormatter

PACKAGE_ROOT = Path(__file__).resolve().parents[1]
TRACE_FILE = PACKAGE_ROOT / "sim" / "world_trace.json"
WORLDS_FILE = PACKAGE_ROOT / "sim" / "worlds.json"
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
# Bumped when what generation writes changes without the world changing.
GENERATOR_FORMAT = 2
COMPONENTS = {
    "physics": "physics and tasks",
    "rgbd": "RGB-D rig",
    "nerf": "NeRF rig",
    "imagery": "imagery settings",
}
RIGS = ("rgbd", "nerf", "imagery")  # the components that render: each has its trace of renders
# The components of a constant other than physics (`<module>:<top-level name>`); any other
# constant of sim/cameras.py belongs to every rig, any other of any module to physics alone.
CONSTANT_COMPONENTS: dict[str, tuple[str, ...]] = {
    "geometry.py:VIEW_GRIDS": ("imagery",),
    "sim/cameras.py:ORTHO_EYE_OFFSET": ("imagery",),
    "sim/cameras.py:RGBD_EYES": ("rgbd",),
    "sim/cameras.py:RGBD_TARGETS": ("rgbd",),
    "sim/cameras.py:NERF_RADIUS": ("nerf",),
    "sim/cameras.py:NERF_ELEVATION": ("nerf",),
    "sim/cameras.py:IMAGE_SIZE": ("rgbd", "nerf"),
    "sim/cameras.py:OPENGL_FROM_OPENCV": ("rgbd", "nerf"),
    # the side camera of videos and of the GUI: no part of any episode
    "sim/env.py:VIDEO_EYE": (),
    "sim/env.py:VIDEO_TARGET": (),
    "sim/env.py:VIDEO_CAMERA": (),
    "sim/env.py:RENDER_MODES": (),
}
# The components a record read, by its imagery. None: a heightmap method (the RGB-D rig) or the
# state method, whose records do not tell them apart: the RGB-D rig is counted for both.
READS = {
    "nerf": ("physics", "imagery", "nerf"),
    "oracle": ("physics", "imagery"),
    None: ("physics", "rgbd"),
}


def _assignments(tree: ast.Module) -> Iterable[tuple[str, str, str]]:
    """(top-level name, assigned name, normalised value text) of every module-level assignment and
    every assignment in a class body."""
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            for inner in node.body:
                for target, value in _assigned(inner):
                    yield node.name, f"{node.name}.{target}", value
        for target, value in _assigned(node):
            yield target.split("[")[0].split(".")[0], target, value


def _assigned(node: ast.stmt) -> list[tuple[str, str]]:
    if isinstance(node, ast.Assign):
        value = ast.unparse(node.value)
        return [(ast.unparse(target), value) for target in node.targets]
    if isinstance(node, ast.AnnAssign | ast.AugAssign) and node.value is not None:
        operator = type(node.op).__name__ if isinstance(node, ast.AugAssign) else ""
        return [(ast.unparse(node.target) + operator, ast.unparse(node.value))]
    return []


def constants(root: Path = PACKAGE_ROOT) -> dict[str, dict[str, str]]:
    """Component -> {`<module>:<name>`: value text} of the world modules' constants."""
    found: dict[str, dict[str, str]] = {name: {} for name in COMPONENTS}
    for pattern in WORLD_MODULES:
        paths = sorted(root.glob(pattern))
        if not paths:
            raise FileNotFoundError(f"world module {pattern} not found under {root}")
        for path in paths:
            module = path.relative_to(root).as_posix()
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for top, name, value in _assignments(tree):
                default = RIGS if module == "sim/cameras.py" else ("physics",)
                for component in CONSTANT_COMPONENTS.get(f"{module}:{top}", default):
                    found[component][f"{module}:{name}"] = value
    return found


def committed_trace(root: Path = PACKAGE_ROOT) -> dict[str, Any]:
    """The committed trace (`sim/world_trace.json` under `root`)."""
    path = root / TRACE_FILE.relative_to(PACKAGE_ROOT)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise FileNotFoundError(
            f"the world's trace {path} is missing or unreadable ({error}); write it with "
            "`python -m nerf_transporter.sim.trace --write`"
        ) from error


def _digest(payload: Any, length: int = 16) -> str:
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:length]


def component_digests(root: Path = PACKAGE_ROOT) -> dict[str, str]:
    """Component -> digest of its constants and its part of the trace."""
    trace = committed_trace(root)
    parts = {"physics": trace["episodes"]} | {rig: trace["renders"][rig] for rig in RIGS}
    found = constants(root)
    return {name: _digest({"constants": found[name], "trace": parts[name]}) for name in COMPONENTS}


def known_worlds(root: Path = PACKAGE_ROOT) -> dict[str, dict[str, Any]]:
    """Fingerprint -> {"format", "components"} of every world recorded in `sim/worlds.json`."""
    path = root / WORLDS_FILE.relative_to(PACKAGE_ROOT)
    return json.loads(path.read_text(encoding="utf-8"))["worlds"]


def float_noise_equals(root: Path = PACKAGE_ROOT) -> dict[str, dict[str, str]]:
    """Component -> {digest: the digest it is recorded as} of the traces `sim/worlds.json` records
    as float noise of a committed one (`same_within_float_noise`)."""
    path = root / WORLDS_FILE.relative_to(PACKAGE_ROOT)
    found: dict[str, dict[str, str]] = {}
    for entry in json.loads(path.read_text(encoding="utf-8")).get("same_within_float_noise", []):
        found.setdefault(entry["component"], {})[entry["digest"]] = entry["same_as"]
    return found


def record_float_noise(
    component: str, digest: str, same_as: str, reason: str, path: Path = WORLDS_FILE
) -> None:
    """Record in `sim/worlds.json` that `digest` of `component` is `same_as` within float noise."""
    if component not in COMPONENTS:
        raise ValueError(f"no world component {component!r}; the components are {list(COMPONENTS)}")
    if not reason.strip():
        raise ValueError("a digest is recorded as another's only with the reason it is the same")
    worlds = json.loads(path.read_text(encoding="utf-8"))
    entry = {"component": component, "digest": digest, "same_as": same_as, "why": reason.strip()}
    entries = worlds.setdefault("same_within_float_noise", [])
    if entry not in entries:
        entries.append(entry)
        write_json(path, worlds)


def world_description(root: Path = PACKAGE_ROOT) -> dict[str, Any]:
    """{"fingerprint", "format", "components": {component: digest}}, as stored with data: a
    component's digest is the one `sim/worlds.json` records it as (`float_noise_equals`), the
    fingerprint the one the world is recorded under there, else the hash of its format and
    components."""
    equals = float_noise_equals(root)
    components = {
        name: equals.get(name, {}).get(digest, digest)
        for name, digest in component_digests(root).items()
    }
    world = {"format": GENERATOR_FORMAT, "components": components}
    recorded = [name for name, known in known_worlds(root).items() if known == world]
    return {"fingerprint": recorded[0] if recorded else _digest(world), **world}


def record_world(description: Mapping[str, Any], path: Path = WORLDS_FILE) -> str:
    """Record the world of `description` in `sim/worlds.json` (if it is not); its fingerprint."""
    worlds = json.loads(path.read_text(encoding="utf-8"))
    entry = {"format": description["format"], "components": dict(description["components"])}
    if entry not in worlds["worlds"].values():
        worlds["worlds"][description["fingerprint"]] = entry
        write_json(path, worlds)
    return description["fingerprint"]


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


def components_of(stored: Mapping[str, Any] | str | None) -> dict[str, Any] | None:
    """{"format", "components"} of a stored world (its description, or only its fingerprint) where
    it is known: this package's world, one recorded in `sim/worlds.json`, or a description that
    holds its components. None for an unknown world (or none)."""
    if isinstance(stored, Mapping):
        if isinstance(stored.get("components"), Mapping):
            return {"format": stored.get("format"), "components": stored["components"]}
        stored = stored.get("fingerprint")
    current = world()
    if stored == current["fingerprint"]:
        return {"format": current["format"], "components": current["components"]}
    return known_worlds().get(stored) if isinstance(stored, str) else None


def world_changes(
    stored: Mapping[str, Any] | str | None,
    current: Mapping[str, Any],
    components: Sequence[str] = tuple(COMPONENTS),
) -> list[str]:
    """What differs between a stored world and `current` (a `world_description()`), in the
    `components` named: one line per component, the format, or an unknown stored world."""
    if stored == current:
        return []
    old, new = components_of(stored), components_of(current)
    if old is None or new is None:
        name = stored.get("fingerprint") if isinstance(stored, Mapping) else stored
        return [f"world {name} is unknown to this package (not in sim/worlds.json)"]
    changes = []
    if old["format"] != new["format"]:
        changes.append(f"generator format {old['format']} -> {new['format']}")
    for component in components:
        if old["components"].get(component) != new["components"].get(component):
            changes.append(f"the {COMPONENTS[component]} ({component}) changed")
    return changes


def components_read(imagery: str | None) -> tuple[str, ...]:
    """The components a record (a cell, a test record, a shipped policy) read, by its imagery."""
    return READS.get(imagery, tuple(COMPONENTS))


def same_world(
    measured: str | None, world: str, components: Sequence[str] = tuple(COMPONENTS)
) -> bool:
    """Whether `measured` (a stored fingerprint) is `world` in every one of `components`."""
    if measured == world:
        return True
    expected = components_of(world)
    return expected is not None and not world_changes(measured, expected, components)


def main(argv: list[str] | None = None) -> int:
    """`nerf-transporter world`: this package's world, component by component."""
    parser = argparse.ArgumentParser(
        prog="nerf-transporter world",
        description="The world fingerprint of this package and the digest of each of its "
        'components (docs/conventions.md, "The world fingerprint").',
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--json", action="store_true", help="print the description as JSON")
    args = parser.parse_args(argv)
    description = world()
    if args.json:
        print(json.dumps(description, indent=2))
        return 0
    print(f"world {description['fingerprint']} (generator format {description['format']})")
    played = component_digests()
    for name, digest in description["components"].items():
        noise = f" (its trace hashes to {played[name]}: float noise of it)" * (
            played[name] != digest
        )
        print(f"  {COMPONENTS[name]:<18} {name:<8} {digest}{noise}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
