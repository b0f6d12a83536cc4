"""Pictures for people: heatmaps with their label and colour bar, markers, captions."""

import numpy as np

from nerf_transporter.drawing import (
    bar_chart,
    captioned,
    draw_marker,
    heatmap_picture,
    line_chart,
    wrap_text,
)


def test_heatmap_picture_rings_the_label_and_ends_in_a_colour_bar():
    colour = np.full((80, 40, 3), 200, dtype=np.uint8)
    heat = np.zeros((80, 40))
    heat[10, 30] = 1.0
    picture = heatmap_picture(colour, heat, label=(60, 20), title="place")
    band = picture.shape[0] - 80  # caption above the image
    assert band > 0 and picture.shape[1] > 40  # the colour bar widens it
    body = picture[band:]
    ring = body[60 - 3 : 60 + 4, 20 - 3 : 20 + 4]
    assert (ring > 200).all(axis=2).any()  # white marker around the label
    assert (body[:, 40:42] == 255).all()  # the gap before the bar
    bar = body[:, 42:].astype(int).sum(axis=2)[:, 0]
    assert bar[0] > bar[-1]  # bright (high) at the top, dark (low) at the bottom
    peak, background = body[10, 30].astype(int), body[40, 10].astype(int)
    assert peak.sum() > background.sum()  # the heat shows where it is


def test_markers_and_captions():
    image = np.zeros((50, 50, 3), dtype=np.uint8)
    draw_marker(image, (25.2, 24.8), "cross")
    assert (image > 200).all(axis=2).any()
    assert wrap_text("one two three four five six", 40, 0.35)[0] != "one two three four five six"
    tall = captioned(image, ["seed 3", "the object did not end at the target pose"])
    assert tall.shape[0] > 50 and (tall[-50:] == image).all()


def _header_ink_columns(image: np.ndarray) -> np.ndarray:
    """Columns of the title and legend band (above the plot area) that hold any non-white pixel."""
    return np.flatnonzero((image[:64] < 250).any(axis=(0, 2)))


def test_charts_widen_to_hold_a_long_title_and_legend():
    names = [f"a method with a long name {i}" for i in range(6)]
    title = "a column with a long name: validation success (20 episodes a round) " * 2
    lines = line_chart(names, [[500, 1000]] * 6, [[0.1, 0.2]] * 6, title=title)
    assert lines.shape[0] == 480 and lines.shape[1] > 800
    assert _header_ink_columns(lines).max() < lines.shape[1] - 5  # nothing cut at the right edge
    bars = bar_chart(
        ["one", "two"],
        names,
        *(np.full((6, 2), 0.5) for _ in range(4)),
        title=title,
        marker_label="paper (Table 1, under its labels)",
    )
    assert bars.shape[1] > 1280
    assert _header_ink_columns(bars).max() < bars.shape[1] - 5
    short = line_chart(["one"], [[1, 2]], [[0.0, 1.0]], title="short")
    assert short.shape[:2] == (480, 800)  # a header that fits keeps the size asked for
