"""Volume rendering inside the workspace box, ended by the opaque floor.

Each ray composites the field's samples in its occupied segments; whatever transmittance is left
where the ray reaches the plane z = 0 is given to the floor map there. Inside the box that is the
box's bottom face; a ray that leaves through a side wall (tilted views near the border) continues
to the same plane, whose colour is the floor map clamped at its border. The depth is the expected
termination distance (floor included) or, where asked, the median one: where the ray's accumulated
opacity first reaches one half, so that a faint layer in front of a surface (a floater, a haze over
a textureless hollow) or a ray grazing an edge does not pull the depth between two surfaces. For
orthographic rays it converts to height. The colour is likewise the rays' weighted mean or, where
asked, the field's colour at the median depth (a surface's colour, not a blend along the ray).

All samples of a batch of rays are evaluated in one pass, packed ray after ray: the fitted
surfaces are rarely opaque enough for early ray termination to pay for marching in rounds, and the
colour is only looked up where a sample's weight matters.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from nerf_transporter.imagery.fields import FloorMap, RadianceField
from nerf_transporter.imagery.rays import Rays
from nerf_transporter.imagery.samplers import OccupancyGrid, RaySamples, occupied_samples


@dataclass(frozen=True)
class MarchSettings:
    """How rays are sampled (segment length, samples per segment) and which samples get a colour."""

    segment_length: float
    samples_per_segment: int
    weight_threshold: float = 1e-4  # samples of lower weight take no colour lookup

    @property
    def step(self) -> float:
        return self.segment_length / self.samples_per_segment


@dataclass
class RayOutput:
    colour: torch.Tensor  # [R, 3] in [0, 1]
    depth: torch.Tensor  # [R] expected termination distance
    alpha: torch.Tensor  # [S] opacity of every sample taken (for regularisers)
    floor_weight: torch.Tensor  # [R] transmittance left for the floor
    weights: torch.Tensor  # [S] each sample's share of its ray (for regularisers)
    samples: RaySamples  # where those samples lie


def _composite(
    field: RadianceField,
    floor: FloorMap,
    rays: Rays,
    samples: RaySamples,
    settings: MarchSettings,
) -> RayOutput:
    """Alpha-composite the packed samples, then give the transmittance left to the floor."""
    points = torch.addcmul(
        rays.origins[samples.ray], samples.t[:, None], rays.directions[samples.ray]
    )
    tau = field.density(points) * settings.step
    alpha = -torch.expm1(-tau)
    weights = torch.exp(-samples.exclusive_sums(tau)) * alpha
    shaded = weights.detach() > settings.weight_threshold
    colour = samples.select(shaded).ray_sums(weights[shaded, None] * field.colour(points[shaded]))
    depth = samples.ray_sums(weights * samples.t)
    remaining = torch.exp(-samples.ray_sums(tau))
    hit = torch.addcmul(rays.origins, rays.floor[:, None], rays.directions)
    colour = colour + remaining[:, None] * floor(hit)
    depth = depth + remaining * rays.floor
    return RayOutput(colour, depth, alpha, remaining, weights, samples)


def render_rays_train(
    field: RadianceField,
    floor: FloorMap,
    occupancy: OccupancyGrid,
    rays: Rays,
    settings: MarchSettings,
    generator: torch.Generator,
) -> RayOutput:
    """Differentiable rendering with stratified jitter (one random offset per occupied segment)."""
    samples = occupied_samples(
        rays, occupancy, settings.segment_length, settings.samples_per_segment, generator
    )
    return _composite(field, floor, rays, samples, settings)


DEPTH_ESTIMATES = ("expected", "median")
COLOUR_ESTIMATES = ("expected", "median")


def median_depth(output: RayOutput, rays: Rays) -> tuple[torch.Tensor, torch.Tensor]:
    """([R] bool, [R]) whether each ray's accumulated weight reaches one half at one of its
    samples, and the distance of the first such sample, or the floor's where the samples' weights
    sum to less (the floor then holds the median)."""
    samples, weights = output.samples, output.weights
    accumulated = samples.exclusive_sums(weights) + weights
    before = samples.ray_sums((accumulated < 0.5).to(weights.dtype)).round().long()
    reached = before < samples.bounds[1:] - samples.bounds[:-1]
    # one padding distance, where the index of a ray that never reaches one half may point
    distances = torch.cat([samples.t, samples.t.new_zeros(1)])
    return reached, torch.where(reached, distances[samples.bounds[:-1] + before], rays.floor)


def median_colour(
    field: RadianceField, floor: FloorMap, rays: Rays, reached: torch.Tensor, depth: torch.Tensor
) -> torch.Tensor:
    """[R, 3] the field's colour at each ray's median depth (`median_depth`'s `reached`, `depth`),
    or the floor's where the ray never reaches one half: a surface's colour, not a blend along the
    ray, so that a pixel at an object's edge takes the object's colour or the table's rather than
    a mix."""
    points = torch.addcmul(rays.origins, depth[:, None], rays.directions)
    colour = floor(points)
    if bool(reached.any()):
        colour[reached] = field.colour(points[reached])
    return colour


@torch.no_grad()
def render_rays(
    field: RadianceField,
    floor: FloorMap,
    occupancy: OccupancyGrid,
    rays: Rays,
    settings: MarchSettings,
    depth: str = "expected",
    colour: str = "expected",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Deterministic rendering at the stratum centres -> (colour [R, 3], depth [R]); `depth` is
    "expected" (the weights' mean distance) or "median" (`median_depth`), `colour` "expected" (the
    weights' mean colour) or "median" (`median_colour`)."""
    if depth not in DEPTH_ESTIMATES:
        raise ValueError(f"unknown depth estimate {depth!r}; expected one of {DEPTH_ESTIMATES}")
    if colour not in COLOUR_ESTIMATES:
        raise ValueError(f"unknown colour estimate {colour!r}; expected one of {COLOUR_ESTIMATES}")
    samples = occupied_samples(
        rays, occupancy, settings.segment_length, settings.samples_per_segment
    )
    output = _composite(field, floor, rays, samples, settings)
    if "median" not in (depth, colour):
        return output.colour, output.depth
    reached, median = median_depth(output, rays)
    if colour == "median":
        return median_colour(field, floor, rays, reached, median), (
            median if depth == "median" else output.depth
        )
    return output.colour, median
