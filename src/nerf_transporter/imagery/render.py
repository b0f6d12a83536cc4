"""Volume rendering inside the workspace box, ended by the opaque floor.

Each ray composites the field's samples in its occupied segments; whatever transmittance is left
where the ray reaches the plane z = 0 is given to the floor map there. Inside the box that is the
box's bottom face; a ray that leaves through a side wall (tilted views near the border) continues
to the same plane, whose colour is the floor map clamped at its border. The expected termination
distance (floor included) is the depth; for orthographic rays it converts to height.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from nerf_transporter.imagery.fields import FloorMap, RadianceField
from nerf_transporter.imagery.rays import Rays
from nerf_transporter.imagery.samplers import OccupancyGrid, occupied_segments, segment_samples


@dataclass(frozen=True)
class MarchSettings:
    """How rays are sampled: segment length, samples per segment, early termination."""

    segment_length: float
    samples_per_segment: int
    segments_per_round: int = 2
    min_transmittance: float = 1e-3
    weight_threshold: float = 1e-4

    @property
    def step(self) -> float:
        return self.segment_length / self.samples_per_segment


@dataclass
class RayOutput:
    colour: torch.Tensor  # [R, 3] in [0, 1]
    depth: torch.Tensor  # [R] expected termination distance
    alpha: torch.Tensor  # [S] opacity of every sample taken (for regularisers)
    floor_weight: torch.Tensor  # [R] transmittance left for the floor


def _composite(
    field: RadianceField,
    rays: Rays,
    t: torch.Tensor,
    valid: torch.Tensor,
    transmittance: torch.Tensor,
    settings: MarchSettings,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Alpha-composite samples t [R, S] -> (colour [R, 3], depth [R], transmittance out [R], alpha)."""
    points = rays.origins[:, None, :] + t[..., None] * rays.directions[:, None, :]
    thickness = field.density(points[valid]) * settings.step
    tau = torch.zeros_like(t).index_put((valid,), thickness)
    cumulative = tau.cumsum(dim=1)
    weights = transmittance[:, None] * torch.exp(tau - cumulative) * (1.0 - torch.exp(-tau))
    shaded = valid & (weights.detach() > settings.weight_threshold)
    rgb = t.new_zeros(*t.shape, 3).index_put((shaded,), field.colour(points[shaded]))
    colour = (weights[..., None] * rgb).sum(dim=1)
    depth = (weights * t).sum(dim=1)
    remaining = transmittance * torch.exp(-cumulative[:, -1]) if t.shape[1] else transmittance
    return colour, depth, remaining, 1.0 - torch.exp(-thickness)


def _end_on_floor(
    floor: FloorMap, rays: Rays, colour: torch.Tensor, depth: torch.Tensor, remaining: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    hit = rays.origins + rays.floor[:, None] * rays.directions
    colour = colour + remaining[:, None] * floor(hit)
    depth = depth + remaining * rays.floor
    return colour, depth


def render_rays_train(
    field: RadianceField,
    floor: FloorMap,
    occupancy: OccupancyGrid,
    rays: Rays,
    settings: MarchSettings,
    generator: torch.Generator,
) -> RayOutput:
    """Differentiable rendering with stratified jitter, all occupied segments at once."""
    start, segments, count = occupied_segments(rays, occupancy, settings.segment_length)
    segment_valid = torch.arange(segments.shape[1], device=count.device) < count[:, None]
    jitter = torch.rand(segments.shape, generator=generator, device=segments.device)
    t, valid = segment_samples(
        rays,
        start,
        segments,
        segment_valid,
        settings.segment_length,
        settings.samples_per_segment,
        jitter,
    )
    ones = torch.ones(len(rays), device=t.device)
    colour, depth, remaining, alpha = _composite(field, rays, t, valid, ones, settings)
    colour, depth = _end_on_floor(floor, rays, colour, depth, remaining)
    return RayOutput(colour, depth, alpha, remaining)


@torch.no_grad()
def render_rays(
    field: RadianceField,
    floor: FloorMap,
    occupancy: OccupancyGrid,
    rays: Rays,
    settings: MarchSettings,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Deterministic rendering (stratum centres) with early ray termination -> (colour, depth).

    Rays march through their occupied segments a few at a time; a ray stops once its transmittance
    falls below `min_transmittance`.
    """
    start, table, count = occupied_segments(rays, occupancy, settings.segment_length)
    device = rays.origins.device
    colour = torch.zeros(len(rays), 3, device=device)
    depth = torch.zeros(len(rays), device=device)
    transmittance = torch.ones(len(rays), device=device)
    active = torch.arange(len(rays), device=device)
    first = 0
    while True:
        keep = (count[active] > first) & (transmittance[active] > settings.min_transmittance)
        active = active[keep]
        if active.numel() == 0:
            break
        segments = table[active, first : first + settings.segments_per_round]
        index = first + torch.arange(segments.shape[1], device=device)
        segment_valid = index < count[active, None]
        subset = rays[active]
        t, valid = segment_samples(
            subset,
            start[active],
            segments,
            segment_valid,
            settings.segment_length,
            settings.samples_per_segment,
            0.5,
        )
        part_colour, part_depth, remaining, _ = _composite(
            field, subset, t, valid, transmittance[active], settings
        )
        colour[active] += part_colour
        depth[active] += part_depth
        transmittance[active] = remaining
        first += settings.segments_per_round
    return _end_on_floor(floor, rays, colour, depth, transmittance)
