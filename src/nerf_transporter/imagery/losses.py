"""Regularisers of the radiance-field fit, each over one batch of rendered rays."""

from __future__ import annotations

import torch

from nerf_transporter.imagery.render import RayOutput


def binary_entropy(probability: torch.Tensor) -> torch.Tensor:
    """Mean entropy of probabilities: low when each is near 0 or 1.

    A textureless table lets a half-transparent object blend to the right colour from every
    camera; applied to the floor's share of each ray, this term makes each ray either end on the
    floor or be stopped by the field.
    """
    p = probability.clamp(1e-6, 1.0 - 1e-6)
    return -(p * p.log() + (1.0 - p) * (1.0 - p).log()).mean()


def distortion(output: RayOutput, step: float, floor_distance: torch.Tensor) -> torch.Tensor:
    """mip-NeRF 360's distortion loss (metres), the mean over the rays.

    Per ray, sum_i sum_j w_i w_j |t_i - t_j| + 1/3 sum_i w_i^2 step over the field's samples
    (intervals of length `step` around their distances t_i) and the floor, a point at
    `floor_distance` [R] carrying the transmittance left: low when a ray's weight sits in one
    short stretch, so that a surface is one thin shell and not density smeared along the ray.
    Evaluated in O(samples) from running sums, the samples being packed nearest first.
    """
    samples, weights = output.samples, output.weights
    before = samples.exclusive_sums(weights)
    before_moment = samples.exclusive_sums(weights * samples.t)
    pairs = 2.0 * samples.ray_sums(weights * (samples.t * before - before_moment))
    spread = samples.ray_sums(weights.square()) * (step / 3.0)
    field_weight = samples.ray_sums(weights)
    field_moment = samples.ray_sums(weights * samples.t)
    floor_pairs = 2.0 * output.floor_weight * (floor_distance * field_weight - field_moment)
    return (pairs + spread + floor_pairs).mean()
