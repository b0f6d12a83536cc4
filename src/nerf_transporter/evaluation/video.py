"""A video of one closed-loop episode: what the robot did and what the policy chose.

Each frame shows the side camera during the robot's motion beside the plan: the top-down view of
the scene before the action with the chosen pick (ring) and place (cross) drawn in, and, for an
imagery method, the place view it chose with the place drawn in. A caption above names task,
setting, seed and method; the closing frames add the outcome (with the pose error where the task
was not achieved). The caption
text also goes to a sidecar `<video>.json`. Written to a temporary name and renamed when done.
"""

from __future__ import annotations

import io
import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import imageio.v2 as imageio
import numpy as np

from nerf_transporter import geometry
from nerf_transporter.drawing import captioned, draw_marker, text_scale, wrap_text

FPS = 30
HOLD_S = 1.5  # the closing frame, with the outcome, is shown this long
BLOCK = 16  # H.264 frame sizes are padded to a multiple of this
OUTCOME_LINES = 2  # caption lines kept for the outcome (the full text is in the sidecar)
log = logging.getLogger(__name__)


def _fit_height(image: np.ndarray, height: int) -> np.ndarray:
    width = max(1, round(image.shape[1] * height / image.shape[0]))
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_NEAREST)


def draw_action(
    top_down: np.ndarray, pick_xyz: Sequence[float], place_xyz: Sequence[float]
) -> np.ndarray:
    """Ring the pick and cross the place (world points) on a top-down view, in place."""
    pixel_size = (geometry.BOUNDS[0, 1] - geometry.BOUNDS[0, 0]) / top_down.shape[1]
    draw_marker(top_down, geometry.world_to_pixel(np.asarray(pick_xyz), pixel_size), "ring")
    draw_marker(top_down, geometry.world_to_pixel(np.asarray(place_xyz), pixel_size), "cross")
    return top_down


def plan_panel(
    top_down: np.ndarray,
    action: dict[str, tuple[np.ndarray, np.ndarray]],
    chosen_view: tuple[np.ndarray, tuple[float, float], str] | None = None,
) -> np.ndarray:
    """The top-down view with pick (ring) and place (cross), and the chosen view (its colour
    image, the place pixel (row, col) in it, its title) beside it."""
    top_down = draw_action(np.array(top_down), action["pick"][0], action["place"][0])
    panels = [captioned(top_down, ["top-down: pick, place"])]
    if chosen_view is not None:
        colour, place_pixel, title = chosen_view
        scale = top_down.shape[0] / colour.shape[0]
        view = _fit_height(np.ascontiguousarray(colour), top_down.shape[0])
        draw_marker(view, (place_pixel[0] * scale, place_pixel[1] * scale), "cross")
        panels.append(captioned(view, [title]))
    height = max(panel.shape[0] for panel in panels)
    panels = [np.pad(p, ((0, height - p.shape[0]), (0, 2), (0, 0))) for p in panels]
    return np.concatenate(panels, axis=1)


class EpisodeVideo:
    """Streams the frames of one episode into `path` (.mp4); `close` adds the outcome.

    The opening frame waits until the plan is known (`begin`), so every frame has one size. A
    video that cannot be written is dropped with a warning: it never changes the episode."""

    def __init__(self, path: str | os.PathLike, header: list[str], opening: np.ndarray) -> None:
        self.path = Path(path)
        self.temporary = self.path.with_name(f".{self.path.stem}-{os.getpid()}.mp4")
        self.header = header
        self.plan: np.ndarray | None = None
        self.last = np.asarray(opening)
        self.frames = 0
        self.broken = False
        self._writer: Any = None

    def _compose(self, frame: np.ndarray, outcome: str = "") -> np.ndarray:
        body = np.concatenate([frame, _fit_height(self.plan, frame.shape[0])], axis=1)
        scale = text_scale(body.shape[1])
        lines = wrap_text(outcome, body.shape[1], scale)[:OUTCOME_LINES] if outcome else []
        lines += [""] * (OUTCOME_LINES - len(lines))
        image = captioned(body, [*self.header, *lines])
        pad_rows, pad_cols = (-image.shape[0]) % BLOCK, (-image.shape[1]) % BLOCK
        return np.pad(image, ((0, pad_rows), (0, pad_cols), (0, 0)))

    def _write(self, image: np.ndarray, copies: int = 1) -> None:
        if self.broken:
            return
        try:
            if self._writer is None:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._writer = imageio.get_writer(self.temporary, fps=FPS, macro_block_size=1)
            for _ in range(copies):
                self._writer.append_data(image)
                self.frames += 1
        except Exception:  # disk full, codec missing: the episode goes on without its video
            log.warning("cannot write the video %s; it is dropped", self.path, exc_info=True)
            self.broken = True

    def begin(self, plan: np.ndarray) -> None:
        """Set the plan panel and show the opening scene for half a second."""
        self.plan = plan
        self._write(self._compose(self.last), FPS // 2)

    def add(self, frame: np.ndarray) -> None:
        """One side-camera frame, composed with the plan and the caption."""
        if self.plan is not None:
            self.last = np.asarray(frame)
            self._write(self._compose(self.last))

    def close(self, outcome: str, record: dict[str, Any]) -> Path | None:
        """Hold the last frame with the `outcome` line, finish the file and write the sidecar
        (caption lines, frame count and the episode's `record`); None when nothing was recorded
        (the episode ended before the robot moved) or the video broke."""
        if self.plan is not None:
            self._write(self._compose(self.last, outcome), round(HOLD_S * FPS))
        if self._writer is not None:
            self._writer.close()
        if self.broken or self._writer is None:
            self.temporary.unlink(missing_ok=True)
            return None
        os.replace(self.temporary, self.path)
        sidecar = {
            "video": self.path.name,
            "caption": [*self.header, outcome],
            "frames": self.frames,
            **record,
        }
        self.path.with_suffix(".json").write_text(json.dumps(sidecar, indent=2) + "\n")
        return self.path


def gif_bytes(
    path: str | os.PathLike, every: int = 3, scale: float = 0.5
) -> tuple[bytes, tuple[int, int]]:
    """A small animated GIF of an episode video (every `every`-th frame at `scale`) and its
    (height, width), for TensorBoard's image tab, which plays GIFs."""
    frames = []
    reader = imageio.get_reader(path)
    try:
        for index, frame in enumerate(reader):
            if index % every == 0:
                size = (round(frame.shape[1] * scale), round(frame.shape[0] * scale))
                frames.append(cv2.resize(frame, size, interpolation=cv2.INTER_AREA))
    finally:
        reader.close()
    buffer = io.BytesIO()
    imageio.mimwrite(buffer, frames, format="GIF", duration=1000 * every / FPS, loop=0)
    return buffer.getvalue(), frames[0].shape[:2]
