"""Pictures for people (TensorBoard images, rollout strips): a heatmap in a colormap over the greyed
scene with a colour bar, markers for labels and actions, and captions. RGB uint8 [H, W, 3] in and
out; nothing here knows about tasks or models.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

Colour = tuple[int, int, int]
MARKER: Colour = (255, 255, 255)  # labels and actions: white with a black outline
CAPTION_BACKGROUND: Colour = (30, 30, 30)
CAPTION_TEXT: Colour = (235, 235, 235)
FONT = cv2.FONT_HERSHEY_SIMPLEX
TITLE_SCALE = 0.6  # a chart's title; its legend and labels are smaller


def _colormap(values: np.ndarray) -> np.ndarray:
    """Values in [0, 1] -> RGB uint8 in the viridis colormap (dark blue low, yellow high)."""
    indices = np.clip(np.round(values * 255), 0, 255).astype(np.uint8)
    return cv2.applyColorMap(indices, cv2.COLORMAP_VIRIDIS)[..., ::-1]


def greyed(colour: np.ndarray) -> np.ndarray:
    """The scene in dimmed grey, so that a colormap drawn over it stands out."""
    grey = cv2.cvtColor(np.ascontiguousarray(colour), cv2.COLOR_RGB2GRAY)
    return np.repeat((0.35 * grey + 40)[..., None], 3, axis=2).astype(np.uint8)


def draw_marker(image: np.ndarray, pixel: Sequence[float], kind: str = "ring") -> np.ndarray:
    """Draw a ring ("ring") or a cross ("cross") centred on pixel (row, col), in place."""
    row, col = (int(round(float(v))) for v in pixel)
    size = max(3, min(image.shape[:2]) // 25)
    for colour, thickness in (((0, 0, 0), 3), (MARKER, 1)):
        if kind == "ring":
            cv2.circle(image, (col, row), size, colour, thickness, cv2.LINE_AA)
        else:
            cv2.drawMarker(image, (col, row), colour, cv2.MARKER_TILTED_CROSS, 2 * size, thickness)
    return image


def text_scale(width: int) -> float:
    """Font scale of captions on an image `width` pixels wide."""
    return max(0.3, min(0.5, width / 480))


def wrap_text(text: str, width: int, scale: float) -> list[str]:
    """Words of `text` in lines that fit `width` pixels at font `scale`."""
    lines: list[str] = []
    for word in text.split():
        candidate = f"{lines[-1]} {word}" if lines else word
        if lines and cv2.getTextSize(candidate, FONT, scale, 1)[0][0] <= width - 4:
            lines[-1] = candidate
        else:
            lines.append(word)
    return lines or [""]


def captioned(
    image: np.ndarray, texts: Sequence[str], text_colour: Colour = CAPTION_TEXT
) -> np.ndarray:
    """`image` under a dark band holding `texts`, each wrapped to the image's width."""
    width = image.shape[1]
    scale = text_scale(width)
    lines = [line for text in texts for line in wrap_text(text, width, scale)]
    line_height = int(cv2.getTextSize("Ag", FONT, scale, 1)[0][1] * 1.8) + 2
    band = np.empty((line_height * len(lines) + 4, width, 3), dtype=np.uint8)
    band[:] = CAPTION_BACKGROUND
    for number, line in enumerate(lines):
        baseline = (number + 1) * line_height - 2
        cv2.putText(band, line, (2, baseline), FONT, scale, text_colour, 1, cv2.LINE_AA)
    return np.concatenate([band, image], axis=0)


def heatmap_picture(
    colour: np.ndarray,
    heat: np.ndarray,
    label: Sequence[float] | None = None,
    title: str = "",
) -> np.ndarray:
    """A heatmap (any non-negative values, e.g. probabilities) over the greyed scene, the label
    pixel (row, col) ringed, and a colour bar from 0 (bottom) to the heatmap's maximum (top)
    whose value the caption gives."""
    heat = np.asarray(heat, dtype=np.float64)
    top = float(heat.max()) if heat.size else 0.0
    normalised = heat / top if top > 0 else np.zeros_like(heat)
    picture = (0.45 * greyed(colour) + 0.55 * _colormap(normalised)).astype(np.uint8)
    if label is not None:
        draw_marker(picture, label)
    height = picture.shape[0]
    bar_width = max(6, picture.shape[1] // 16)
    gradient = np.linspace(1.0, 0.0, height)[:, None].repeat(bar_width, axis=1)
    gap = np.full((height, 2, 3), 255, dtype=np.uint8)
    body = np.concatenate([picture, gap, _colormap(gradient)], axis=1)
    return captioned(body, [f"{title} max {top:.2g}".strip()])


def _centred_text(image: np.ndarray, text: str, centre_x: int, baseline: int, scale: float) -> None:
    width = cv2.getTextSize(text, FONT, scale, 1)[0][0]
    cv2.putText(
        image, text, (centre_x - width // 2, baseline), FONT, scale, (40, 40, 40), 1, cv2.LINE_AA
    )


GRID: Colour = (225, 225, 225)
INK: Colour = (40, 40, 40)


def _fraction_axis(image: np.ndarray, box: tuple[int, int, int, int], scale: float):
    """Grid lines and percent labels of a [0, 1] vertical axis in `box` (left, right, top,
    bottom), drawn in place; returns the function from a fraction to its image row."""
    left, right, top, bottom = box

    def y_of(fraction: float) -> int:
        return int(round(bottom - fraction * (bottom - top)))

    for tick in np.linspace(0, 1, 6):
        y = y_of(tick)
        cv2.line(image, (left, y), (right, y), GRID, 1)
        label = f"{100 * tick:.0f}%"
        label_width = cv2.getTextSize(label, FONT, scale, 1)[0][0]
        cv2.putText(image, label, (left - 8 - label_width, y + 5), FONT, scale, INK, 1, cv2.LINE_AA)
    cv2.line(image, (left, bottom), (right, bottom), INK, 1)
    return y_of


def _series_colours(count: int) -> list[Colour]:
    return [
        tuple(int(c) for c in colour)
        for colour in _colormap(np.linspace(0.05, 0.9, count)[None])[0]
    ]


def _legend_entry_width(name: str, scale: float) -> int:
    """Pixels one legend entry takes: swatch, its name and the gap before the next."""
    return 20 + cv2.getTextSize(name, FONT, scale, 1)[0][0] + 24


def _header_width(left: int, title: str, entries: Sequence[str], scale: float) -> int:
    """The x up to which `_title_and_legend` draws a title and a legend of `entries`."""
    title_end = left + cv2.getTextSize(title, FONT, TITLE_SCALE, 1)[0][0] if title else left
    legend_end = left + sum(_legend_entry_width(name, scale) for name in entries)
    return max(title_end, legend_end)


def _canvas(size: tuple[int, int], header: int) -> np.ndarray:
    """A white RGB canvas of `size`, widened where the header (title and legend) needs it."""
    height, width = size
    return np.full((height, max(width, header + 10), 3), 255, dtype=np.uint8)


def _title_and_legend(
    image: np.ndarray, left: int, title: str, series: Sequence[str], scale: float
) -> int:
    """The title and one colour swatch per series along the top, in place; returns the x after the
    legend."""
    if title:
        cv2.putText(image, title, (left, 24), FONT, TITLE_SCALE, (20, 20, 20), 1, cv2.LINE_AA)
    x = left
    for colour, name in zip(_series_colours(len(series)), series, strict=True):
        cv2.rectangle(image, (x, 44), (x + 14, 58), colour, cv2.FILLED)
        cv2.putText(image, name, (x + 20, 56), FONT, scale, INK, 1, cv2.LINE_AA)
        x += _legend_entry_width(name, scale)
    return x


def bar_chart(
    groups: Sequence[str],
    series: Sequence[str],
    values: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    markers: np.ndarray,
    *,
    title: str = "",
    marker_label: str = "",
    size: tuple[int, int] = (560, 1280),
) -> np.ndarray:
    """Grouped bars of fractions in [0, 1] on a white canvas (RGB uint8 [H, W, 3]).

    `values`, `low`, `high` and `markers` are [len(series), len(groups)]: bar heights, the ends of
    each bar's whisker, and a black diamond per bar slot (e.g. a reference value); NaN leaves a
    bar (its slot shows "-") or a marker out. Series are told apart by colour, named in a legend;
    a group's name may hold one line break. The canvas is `size`, widened where the title or the
    legend would not fit it.
    """
    values, low, high, markers = (
        np.asarray(a, dtype=np.float64) for a in (values, low, high, markers)
    )
    shape = (len(series), len(groups))
    if any(array.shape != shape for array in (values, low, high, markers)):
        raise ValueError(f"values, low, high and markers must all be [series, groups] = {shape}")
    left, scale = 60, 0.45
    legend = [*series, marker_label] if marker_label else list(series)
    image = _canvas(size, _header_width(left, title, legend, scale))
    height, width = image.shape[:2]
    right, top, bottom = width - 20, 80, height - 50
    y_of = _fraction_axis(image, (left, right, top, bottom), scale)
    colours = _series_colours(len(series))
    group_width = (right - left) / len(groups)
    bar_width = group_width * 0.8 / len(series)
    for g, group in enumerate(groups):
        start = left + g * group_width + 0.1 * group_width
        for line, text in enumerate(group.split("\n")):
            centre_x = int(left + (g + 0.5) * group_width)
            _centred_text(image, text, centre_x, bottom + 22 + 16 * line, scale)
        for s in range(len(series)):
            x0, x1 = int(start + s * bar_width + 1), int(start + (s + 1) * bar_width - 1)
            centre = (x0 + x1) // 2
            if np.isnan(values[s, g]):
                _centred_text(image, "-", centre, bottom - 4, scale)
            else:
                cv2.rectangle(image, (x0, y_of(values[s, g])), (x1, bottom), colours[s], cv2.FILLED)
                y_low, y_high = y_of(low[s, g]), y_of(high[s, g])
                cv2.line(image, (centre, y_low), (centre, y_high), (20, 20, 20), 1, cv2.LINE_AA)
                for y in (y_low, y_high):
                    cv2.line(image, (centre - 4, y), (centre + 4, y), (20, 20, 20), 1, cv2.LINE_AA)
            if not np.isnan(markers[s, g]):
                cv2.drawMarker(
                    image, (centre, y_of(markers[s, g])), (0, 0, 0), cv2.MARKER_DIAMOND, 10, 2
                )
    x = _title_and_legend(image, left, title, series, scale)
    if marker_label:
        cv2.drawMarker(image, (x + 7, 51), (0, 0, 0), cv2.MARKER_DIAMOND, 10, 2)
        cv2.putText(image, marker_label, (x + 20, 56), FONT, scale, INK, 1, cv2.LINE_AA)
    return image


def line_chart(
    series: Sequence[str],
    x_values: Sequence[Sequence[float]],
    fractions: Sequence[Sequence[float]],
    *,
    title: str = "",
    x_label: str = "",
    size: tuple[int, int] = (480, 800),
) -> np.ndarray:
    """One polyline with dots per series of fractions in [0, 1] against x (RGB uint8 [H, W, 3]);
    the x axis runs from 0 to the largest x, series are told apart by colour, named in a legend;
    the canvas is `size`, widened where the title or the legend would not fit it."""
    if not (len(series) == len(x_values) == len(fractions)):
        raise ValueError("series, x_values and fractions must have one entry per series")
    if any(len(xs) != len(ys) for xs, ys in zip(x_values, fractions, strict=True)):
        raise ValueError("each series needs as many x values as fractions")
    x_max = max((max(xs) for xs in x_values if len(xs)), default=0) or 1
    left, scale = 60, 0.45
    image = _canvas(size, _header_width(left, title, series, scale))
    height, width = image.shape[:2]
    right, top, bottom = width - 30, 80, height - 50
    y_of = _fraction_axis(image, (left, right, top, bottom), scale)

    def x_of(value: float) -> int:
        return int(round(left + value / x_max * (right - left)))

    for tick in np.linspace(0, x_max, 5):
        _centred_text(image, f"{tick:g}", x_of(tick), bottom + 20, scale)
    if x_label:
        _centred_text(image, x_label, (left + right) // 2, bottom + 40, scale)
    for colour, xs, ys in zip(_series_colours(len(series)), x_values, fractions, strict=True):
        points = np.array([(x_of(x), y_of(y)) for x, y in zip(xs, ys, strict=True)], dtype=np.int32)
        if len(points) > 1:
            cv2.polylines(image, [points], False, colour, 2, cv2.LINE_AA)
        for point in points:
            cv2.circle(image, tuple(int(v) for v in point), 4, colour, cv2.FILLED, cv2.LINE_AA)
    _title_and_legend(image, left, title, series, scale)
    return image
