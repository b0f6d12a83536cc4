"""Imagery quality against ground-truth orthographic renders: colour PSNR and height error."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

OBJECT_HEIGHT = 0.005  # pixels whose ground-truth height exceeds this (m) belong to objects
EDGE_GRADIENT = 10.0  # grey levels a pixel: a colour edge (a bowl's rim, a disk's outline)


def psnr(prediction: np.ndarray, target: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of uint8 images (any matching shape)."""
    prediction, target = np.asarray(prediction), np.asarray(target)
    if prediction.shape != target.shape:
        raise ValueError(f"shape mismatch: {prediction.shape} vs {target.shape}")
    error = np.mean((prediction.astype(np.float64) - target.astype(np.float64)) ** 2)
    return float("inf") if error == 0 else float(10.0 * np.log10(255.0**2 / error))


def height_mae_mm(
    prediction: np.ndarray, target: np.ndarray, object_height: float = OBJECT_HEIGHT
) -> tuple[float, float]:
    """Mean absolute height error in mm over all pixels and over object pixels (target > object_height).

    The object figure is NaN when no pixel of the target is above `object_height`.
    """
    prediction, target = (
        np.asarray(prediction, dtype=np.float64),
        np.asarray(target, dtype=np.float64),
    )
    if prediction.shape != target.shape:
        raise ValueError(f"shape mismatch: {prediction.shape} vs {target.shape}")
    error = np.abs(prediction - target) * 1000.0
    objects = target > object_height
    overall = float(error.mean())
    on_objects = float(error[objects].mean()) if objects.any() else float("nan")
    return overall, on_objects


def footprint_errors(
    prediction: np.ndarray, target: np.ndarray, object_height: float = OBJECT_HEIGHT
) -> dict[str, float]:
    """How a top-down height image's objects (pixels above `object_height`) cover the target's:
    the pixels it adds (`extra_px`), those it leaves out (`missing_px`) and the intersection over
    union (`iou`; NaN where neither has an object). A radiance field's objects come out fatter
    than they are (docs/imagery.md, "The median colour, and renderings cached from one fit")."""
    prediction, target = np.asarray(prediction), np.asarray(target)
    if prediction.shape != target.shape:
        raise ValueError(f"shape mismatch: {prediction.shape} vs {target.shape}")
    predicted, true = prediction > object_height, target > object_height
    union = int((predicted | true).sum())
    return {
        "extra_px": float((predicted & ~true).sum()),
        "missing_px": float((true & ~predicted).sum()),
        "iou": float((predicted & true).sum()) / union if union else float("nan"),
    }


def colour_edges(image: np.ndarray, gradient: float = EDGE_GRADIENT, width: int = 1) -> np.ndarray:
    """Boolean mask [H, W] of the pixels at colour edges of a uint8 image [H, W, 3]: where the
    grey level (the channels' mean) changes by more than `gradient` a pixel (central differences),
    grown by `width` pixels on each side. The imagery's colour error gathers there, where a
    radiance field blurs outlines (docs/imagery.md), so its PSNR is scored apart."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"expected an [H, W, 3] colour image, got shape {image.shape}")
    grey = image.astype(np.float64).mean(axis=-1)
    d_row, d_col = np.gradient(grey)
    edges = np.hypot(d_row, d_col) > gradient
    return ndimage.binary_dilation(edges, iterations=width) if width > 0 else edges
