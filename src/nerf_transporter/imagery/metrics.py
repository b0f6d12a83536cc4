"""Imagery quality against ground-truth orthographic renders: colour PSNR and height error."""

from __future__ import annotations

import numpy as np

OBJECT_HEIGHT = 0.005  # pixels whose ground-truth height exceeds this (m) belong to objects


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
