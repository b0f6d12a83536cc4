"""Where to sample along rays: an occupancy grid for empty-space skipping and stratified samples.

A ray's box interval is cut into segments of `segment_length`; only segments whose midpoint lies in
an occupied cell (the grid is dilated by one cell, so this is conservative) receive
`samples_per_segment` stratified samples, packed ray after ray (`RaySamples`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from nerf_transporter import geometry
from nerf_transporter.imagery.fields import BOX_EXTENT
from nerf_transporter.imagery.rays import Rays, box_interval


class OccupancyGrid:
    """Coarse boolean grid over the workspace box: False where the field is (nearly) empty."""

    def __init__(self, cells: tuple[int, int, int], device: torch.device | str = "cpu") -> None:
        self.cells = cells  # (x, y, z)
        nx, ny, nz = cells
        self.low = torch.tensor(geometry.BOUNDS[:, 0], dtype=torch.float32, device=device)
        self.cell_size = torch.tensor(
            BOX_EXTENT, dtype=torch.float32, device=device
        ) / torch.tensor(cells, dtype=torch.float32, device=device)
        self.zero = torch.zeros(3, dtype=torch.long, device=device)
        self.last = torch.tensor(cells, dtype=torch.long, device=device) - 1
        self.strides = torch.tensor((1, nx, nx * ny), dtype=torch.long, device=device)
        self.set_mask(torch.ones(nz, ny, nx, dtype=torch.bool, device=device))

    def set_mask(self, mask: torch.Tensor) -> None:
        """Replace the occupancy [Z, Y, X] and recompute the bounding box of its occupied cells."""
        self.mask = mask
        self.full = bool(mask.all())  # every cell occupied: no lookups needed
        if not mask.any():
            self.bbox = (self.low, self.low)
            return
        first, last = [], []
        for dim in (2, 1, 0):  # x, y, z axes of the [Z, Y, X] mask
            other = tuple(d for d in range(3) if d != dim)
            indices = torch.nonzero(mask.any(dim=other))[:, 0]
            first.append(indices[0])
            last.append(indices[-1] + 1)
        first_t = torch.stack(first).float()
        last_t = torch.stack(last).float()
        self.bbox = (self.low + first_t * self.cell_size, self.low + last_t * self.cell_size)

    def update(self, lattice: torch.Tensor, threshold: float) -> None:
        """Mark cells holding any lattice density above `threshold` (per metre), then dilate by one cell."""
        nx, ny, nz = self.cells
        peak = F.adaptive_max_pool3d(lattice[None, None].float(), (nz, ny, nx))
        occupied = (peak > threshold).float()
        self.set_mask(F.max_pool3d(occupied, 3, stride=1, padding=1)[0, 0] > 0)

    def lookup(self, points: torch.Tensor) -> torch.Tensor:
        """Occupancy at world points [..., 3] -> bool [...] (points outside: the nearest cell)."""
        index = ((points - self.low) / self.cell_size).long().clamp_(min=self.zero, max=self.last)
        return self.mask.view(-1)[(index * self.strides).sum(dim=-1)]

    @property
    def fraction(self) -> float:
        """Fraction of occupied cells."""
        return float(self.mask.float().mean())


@dataclass
class RaySamples:
    """Samples packed ray after ray, nearest first: sample i lies on ray `ray[i]` at distance `t[i]`.

    The samples of ray r are `bounds[r]:bounds[r + 1]`. Packing (rather than padding every ray to
    the longest one) keeps every tensor as long as the number of samples actually taken.
    """

    t: torch.Tensor  # [N]
    ray: torch.Tensor  # [N] long, non-decreasing
    bounds: torch.Tensor  # [R + 1] long

    def __len__(self) -> int:
        return self.t.shape[0]

    def select(self, mask: torch.Tensor) -> RaySamples:
        """The samples where `mask` [N] is True, still packed ray after ray."""
        kept = torch.cat([mask.new_zeros(1, dtype=torch.long), mask.long().cumsum(0)])
        return RaySamples(self.t[mask], self.ray[mask], kept[self.bounds])

    def _prefix_sums(self, values: torch.Tensor) -> torch.Tensor:
        """Inclusive running sums [N + 1, ...] in float64, with a leading zero row."""
        cumulative = values.double().cumsum(0)
        return torch.cat([cumulative.new_zeros(1, *values.shape[1:]), cumulative])

    def ray_sums(self, values: torch.Tensor) -> torch.Tensor:
        """Per-ray sums of per-sample values [N, ...] -> [R, ...] (0 for rays without samples).

        Differences of float64 running sums: deterministic on every device (no atomic adds).
        """
        prefix = self._prefix_sums(values)
        return (prefix[self.bounds[1:]] - prefix[self.bounds[:-1]]).to(values.dtype)

    def exclusive_sums(self, values: torch.Tensor) -> torch.Tensor:
        """Sum of the values [N] of the earlier samples of the same ray, per sample -> [N]."""
        prefix = self._prefix_sums(values)
        return (prefix[:-1] - prefix[self.bounds[:-1]][self.ray]).to(values.dtype)


def occupied_samples(
    rays: Rays,
    occupancy: OccupancyGrid,
    segment_length: float,
    samples_per_segment: int,
    generator: torch.Generator | None = None,
) -> RaySamples:
    """Stratified samples in each ray's occupied segments, packed ray after ray.

    Segments are cut from where the ray enters the bounding box of the occupied cells, segment k
    spanning start + [k, k + 1) * segment_length; a segment is occupied when its midpoint (clamped
    to the ray's end) lies in an occupied cell. Each occupied segment gets `samples_per_segment`
    strata, sampled at a uniform random offset drawn from `generator` (one per segment), or at the
    stratum centres without a generator; samples beyond the ray's `far` are dropped.
    """
    low, high = occupancy.bbox
    entry, exit_ = box_interval(rays.origins, rays.directions, low, high)
    start = torch.maximum(rays.near, entry)
    end = torch.minimum(rays.far, exit_)
    crossing = torch.nonzero(end > start)[:, 0]  # only these rays are cut into segments
    start_c, end_c = start[crossing], end[crossing]
    span = float((end_c - start_c).max()) if len(crossing) else 0.0
    total = int(math.ceil(span / segment_length))
    starts = start_c[:, None] + segment_length * torch.arange(total, device=start.device)
    inside = starts < end_c[:, None]
    if occupancy.full:
        occupied = inside
    else:
        middle = torch.minimum(starts + 0.5 * segment_length, end_c[:, None])
        points = torch.addcmul(
            rays.origins[crossing, None, :], middle[..., None], rays.directions[crossing, None, :]
        )
        occupied = inside & occupancy.lookup(points)
    ray, segment = torch.nonzero(occupied, as_tuple=True)
    ray = crossing[ray]
    step = segment_length / samples_per_segment
    offsets = torch.arange(samples_per_segment, device=start.device, dtype=torch.float32)
    if generator is None:
        offsets = (offsets + 0.5).expand(len(ray), -1)
    else:
        jitter = torch.rand(len(ray), 1, generator=generator, device=start.device)
        offsets = offsets + jitter
    t = (start[ray, None] + segment[:, None] * segment_length + offsets * step).flatten()
    ray = ray.repeat_interleave(samples_per_segment)
    keep = t < rays.far[ray]
    t, ray = t[keep], ray[keep]
    bounds = torch.searchsorted(ray, torch.arange(len(rays) + 1, device=ray.device))
    return RaySamples(t, ray, bounds)
