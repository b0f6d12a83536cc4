"""The world's trace: a short fixed-seed record of what the simulator does, shipped in the package.

For every task and setting, seed `SEED`: the pose of every body after reset, the oracle's action,
every pose once the scene has settled after it, the outcome (success, strict success, pose errors),
and the procedural assets the episode built (name and a digest of each file's content). Then a fixed
scene of coloured boxes, built here without any task asset, is rendered by the RGB-D rig, the NeRF
rig and a few orthographic views of the view grid, each image summarised by its mean colour (and
mean depth or height); so the rigs' part of the trace changes with the rigs and the renderer only.

Poses are positions and rotation matrices; numbers are rounded to `DECIMALS` places (0.1 mm, 1e-4
of a rotation matrix's entry or of a colour in [0, 1]).
`sim/world_trace.json` holds the committed trace, which the world fingerprint hashes
(`sim/fingerprint.py`): it needs no simulator to be read. `matches` compares a trace played again
with it, within `TOLERANCE` (float noise of another CPU, a value rounded the other way) and exactly
for everything that is not a number; a test plays it in the default suite, so a change of behaviour
fails there until the trace is written again:

    python -m nerf_transporter.sim.trace --write

which also records the new world in `sim/worlds.json` (see `sim/fingerprint.py`); with
`--same-world REASON` it records a trace that moved by float noise alone as the committed world's.
"""

from __future__ import annotations

import argparse
import hashlib
import inspect
import math
import os
import re
import sys
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from nerf_transporter import geometry
from nerf_transporter.atomic import write_json
from nerf_transporter.console import HelpFormatter
from nerf_transporter.sim import assets, cameras, fingerprint
from nerf_transporter.sim.env import connect, make_env
from nerf_transporter.sim.tasks import SETTINGS, TASKS

SEED = 0
DECIMALS = 4
TOLERANCE = 5e-4  # a replayed number may differ this much from the committed one
RENDER_SIZE = (60, 80)  # (rows, cols) of the rigs' renders: the rigs' cameras, scaled down
RENDER_PIXEL_SIZE = 0.0125  # m per pixel of the orthographic renders (40 x 80)
ASSET_NAME = re.compile(r"^(.*)-[0-9a-f]{16}(\.\w+)$")  # assets.cached_file's `<name>-<hash><sfx>`
# The fixed scene of the rigs' renders: (half extents, centre, rgba) of each box.
RENDER_BOXES = (
    ((0.4, 0.6, 0.01), (0.5, 0.0, -0.01), (0.82, 0.78, 0.72, 1.0)),
    ((0.03, 0.05, 0.02), (0.42, -0.12, 0.02), (0.84, 0.15, 0.16, 1.0)),
    ((0.04, 0.04, 0.05), (0.6, 0.1, 0.05), (0.17, 0.63, 0.17, 1.0)),
    ((0.06, 0.02, 0.01), (0.5, 0.25, 0.01), (0.12, 0.47, 0.71, 1.0)),
)


def _rounded(values: Any) -> list[float]:
    return [round(float(v), DECIMALS) + 0.0 for v in np.ravel(values)]  # + 0.0: no -0.0


def _pose(position: Sequence[float], quat: Sequence[float]) -> list[float]:
    """xyz then the rotation matrix, row by row (a quaternion's sign is arbitrary: q and -q are
    one rotation, and a rotation of w = 0 would flip with float noise)."""
    return _rounded(np.concatenate([position, geometry.quat_to_matrix(quat).ravel()]))


def _scene_poses(env: Any) -> list[list[float]]:
    client = env.client
    bodies = [client.getBodyUniqueId(k) for k in range(client.getNumBodies())]
    return [_pose(*assets.get_pose(client, body)) for body in bodies]


def _plain(value: Any) -> Any:
    """An info value as JSON: numbers rounded, arrays as lists."""
    if isinstance(value, dict):
        return {str(key): _plain(item) for key, item in sorted(value.items())}
    if isinstance(value, bool | str) or value is None:
        return value
    if isinstance(value, int | np.integer) and not isinstance(value, np.bool_):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    rounded = _rounded(value)
    return rounded[0] if np.ndim(value) == 0 else rounded


def _asset_digests(folder: Path) -> list[str]:
    """`<name><suffix> <digest>` of every asset file in `folder`, its path taken out of the text
    (an asset names its meshes by absolute path)."""
    entries = []
    for path in sorted(folder.iterdir()):
        match = ASSET_NAME.fullmatch(path.name)
        name = f"{match.group(1)}{match.group(2)}" if match else path.name
        text = path.read_text(encoding="utf-8").replace(str(folder), "<assets>")
        entries.append(f"{name} {hashlib.sha256(text.encode()).hexdigest()[:12]}")
    return sorted(entries)


@contextmanager
def _asset_folder() -> Iterator[Path]:
    """A fresh, empty asset cache for the duration (the episode then writes every asset it uses)."""
    saved = os.environ.get("NERF_TRANSPORTER_CACHE")
    with tempfile.TemporaryDirectory(prefix="world-trace-") as folder:
        os.environ["NERF_TRANSPORTER_CACHE"] = folder
        try:
            yield Path(folder)
        finally:
            if saved is None:
                del os.environ["NERF_TRANSPORTER_CACHE"]
            else:
                os.environ["NERF_TRANSPORTER_CACHE"] = saved


def episode_trace(task: str, setting: str, seed: int = SEED) -> dict[str, Any]:
    """Seed `seed` of `task` in `setting`: poses after reset, the oracle's action, poses settled
    after it, its outcome and the assets the episode built."""
    with _asset_folder() as folder:
        env = make_env(task, setting)
        try:
            env.reset(seed=seed)
            reset = _scene_poses(env)
            action = env.task.oracle(env)
            _, reward, _, _, info = env.step(action)
            settled = _scene_poses(env)
        finally:
            env.close()
        built = _asset_digests(folder)
    return {
        "seed": seed,
        "assets": built,
        "reset": reset,
        "action": {name: _pose(*pose) for name, pose in sorted(action.items())},
        "settled": settled,
        "outcome": _plain({**info, "reward": reward}),
    }


def _render_scene() -> Any:
    """A client holding the fixed scene of `RENDER_BOXES` (PyBullet's own shapes, no assets)."""
    client = connect()
    for half_extents, centre, rgba in RENDER_BOXES:
        client.createMultiBody(
            baseMass=0.0,
            baseVisualShapeIndex=client.createVisualShape(
                client.GEOM_BOX, halfExtents=half_extents, rgbaColor=rgba
            ),
            basePosition=centre,
        )
    return client


def _image_summary(colour: np.ndarray, *distance: np.ndarray) -> list[float]:
    """Mean colour in [0, 1] (per channel), then the mean of each `distance` image (metres)."""
    means = [*np.asarray(colour, dtype=float).reshape(-1, 3).mean(axis=0) / 255]
    return _rounded(means + [float(np.mean(d, dtype=float)) for d in distance])


def render_trace() -> dict[str, list[list[float]]]:
    """The fixed scene seen by each rig (at `RENDER_SIZE`) and by views of the grid."""
    scale = RENDER_SIZE[1] / cameras.IMAGE_SIZE[1]
    focal = inspect.signature(cameras.rgbd_cameras).parameters["focal"].default * scale
    client = _render_scene()
    try:
        rgbd = cameras.capture(client, cameras.rgbd_cameras(RENDER_SIZE, focal), depth=True)
        nerf = cameras.capture(client, cameras.nerf_cameras(image_size=RENDER_SIZE))
        grid = geometry.view_grid("challenging")
        views = [
            cameras.render_orthographic(client, roll, pitch, RENDER_PIXEL_SIZE)
            for roll, pitch in grid[:: max(1, len(grid) // 4)]
        ]
    finally:
        client.disconnect()
    return {
        "rgbd": [_image_summary(c, d) for c, d in zip(rgbd["rgb"], rgbd["depth"], strict=True)],
        "nerf": [_image_summary(c) for c in nerf["rgb"]],
        "imagery": [_image_summary(colour, height) for colour, height in views],
    }


def world_trace() -> dict[str, Any]:
    """The trace of this checkout's simulator (see the module docstring)."""
    episodes = {
        f"{task}/{setting}": episode_trace(task, setting)
        for task in sorted(TASKS)
        for setting in SETTINGS
    }
    return {"seed": SEED, "decimals": DECIMALS, "episodes": episodes, "renders": render_trace()}


def differences(
    committed: Any, replayed: Any, where: str = "trace", tolerance: float = TOLERANCE
) -> list[str]:
    """Where `replayed` differs from `committed`: numbers by more than `tolerance`, anything else
    at all; one line each."""
    if isinstance(committed, dict) and isinstance(replayed, dict):
        lines = []
        for key in sorted(set(committed) | set(replayed)):
            if key not in committed or key not in replayed:
                lines.append(
                    f"{where}.{key}: only in the {'replayed' if key in replayed else 'committed'} trace"
                )
            else:
                lines.extend(
                    differences(committed[key], replayed[key], f"{where}.{key}", tolerance)
                )
        return lines
    if isinstance(committed, list) and isinstance(replayed, list):
        if len(committed) != len(replayed):
            return [f"{where}: {len(committed)} entries committed, {len(replayed)} replayed"]
        return [
            line
            for index, (old, new) in enumerate(zip(committed, replayed, strict=True))
            for line in differences(old, new, f"{where}[{index}]", tolerance)
        ]
    numbers = (int, float)
    if (
        isinstance(committed, numbers)
        and isinstance(replayed, numbers)
        and not isinstance(committed, bool)
        and not isinstance(replayed, bool)
    ):
        if math.isclose(committed, replayed, rel_tol=0.0, abs_tol=tolerance):
            return []
    elif committed == replayed:
        return []
    return [f"{where}: committed {committed!r}, replayed {replayed!r}"]


def main(argv: list[str] | None = None) -> int:
    """`python -m nerf_transporter.sim.trace [--write]`: play the trace, compare or write it."""
    parser = argparse.ArgumentParser(
        prog="python -m nerf_transporter.sim.trace",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "--write",
        action="store_true",
        help="write the trace played here to sim/world_trace.json and record the world it makes "
        "in sim/worlds.json (default: compare it with the committed one)",
    )
    parser.add_argument(
        "--same-world",
        metavar="REASON",
        help="with --write: the trace differs from the committed one by float noise alone (the "
        "same constants' values, assets and outcomes; numbers moved by arithmetic done in "
        "another order): record each component digest it changes as the committed one's, with "
        "REASON, so the world keeps its name. Refused where anything but a number differs",
    )
    args = parser.parse_args(argv)
    if args.same_world is not None and not args.write:
        parser.error("--same-world records a written trace: give --write too")
    if args.same_world is not None and not args.same_world.strip():
        parser.error("--same-world needs the reason the trace is the same world's")
    replayed = world_trace()
    if args.write:
        if args.same_world is not None:
            committed_world = fingerprint.world_description()  # the committed trace's world
            if committed_world["fingerprint"] not in fingerprint.known_worlds():
                print(
                    "refused: with the committed trace, this code's constants make no recorded "
                    "world (sim/worlds.json): a changed constant is another world, written "
                    "without --same-world",
                    file=sys.stderr,
                )
                return 1
            beyond_numbers = differences(
                fingerprint.committed_trace(), replayed, tolerance=math.inf
            )
            if beyond_numbers:
                print("\n".join(beyond_numbers), file=sys.stderr)
                print(
                    f"refused: the trace played here differs from {fingerprint.TRACE_FILE} in "
                    f"{len(beyond_numbers)} entries that are not numbers (assets, outcomes, "
                    "bodies): that is another world, written without --same-world",
                    file=sys.stderr,
                )
                return 1
        write_json(fingerprint.TRACE_FILE, replayed, sort_keys=True)
        if args.same_world is not None:
            for name, digest in fingerprint.component_digests().items():
                if digest != committed_world["components"][name]:
                    fingerprint.record_float_noise(
                        name, digest, committed_world["components"][name], args.same_world
                    )
        world = fingerprint.record_world(fingerprint.world_description())
        print(f"wrote {fingerprint.TRACE_FILE}; the world is {world}")
        return 0
    lines = differences(fingerprint.committed_trace(), replayed)
    if lines:
        print("\n".join(lines), file=sys.stderr)
        print(f"{len(lines)} differences from {fingerprint.TRACE_FILE}", file=sys.stderr)
        return 1
    print(f"the simulator plays {fingerprint.TRACE_FILE} as committed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
