"""Where to sample along rays: an occupancy grid for empty-space skipping and stratified samples.

A ray's box interval is cut into segments of `segment_length`; only segments whose midpoint lies in
an occupied cell (the grid is dilated by one cell, so this is conservative) receive
`samples_per_segment` stratified samples.
"""

from __future__ import annotations

import math

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
        self.set_mask(torch.ones(nz, ny, nx, dtype=torch.bool, device=device))

    def set_mask(self, mask: torch.Tensor) -> None:
        """Replace the occupancy [Z, Y, X] and recompute the bounding box of its occupied cells."""
        self.mask = mask
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
        """Occupancy at world points [..., 3] -> bool [...]."""
        index = ((points - self.low) / self.cell_size).long()
        nx, ny, nz = self.cells
        ix = index[..., 0].clamp(0, nx - 1)
        iy = index[..., 1].clamp(0, ny - 1)
        iz = index[..., 2].clamp(0, nz - 1)
        return self.mask.view(-1)[(iz * ny + iy) * nx + ix]

    @property
    def fraction(self) -> float:
        """Fraction of occupied cells."""
        return float(self.mask.float().mean())


def occupied_segments(
    rays: Rays, occupancy: OccupancyGrid, segment_length: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each ray's occupied segments, nearest first: (start [R], table [R, S] long, count [R] long).

    Segments are cut from `start`, where the ray enters the bounding box of the occupied cells;
    table[r, :count[r]] are the occupied segment indices of ray r in increasing distance (the rest
    of the row is padding), segment k spanning start + [k, k + 1) * segment_length.
    """
    low, high = occupancy.bbox
    entry, exit_ = box_interval(rays.origins, rays.directions, low, high)
    start = torch.maximum(rays.near, entry)
    end = torch.minimum(rays.far, exit_)
    span = (end - start).clamp(min=0.0)
    total = int(math.ceil(float(span.max()) / segment_length)) if len(rays) else 0
    starts = start[:, None] + segment_length * torch.arange(total, device=start.device)
    inside = starts < end[:, None]
    middle = torch.minimum(starts + 0.5 * segment_length, end[:, None])
    points = rays.origins[:, None, :] + middle[..., None] * rays.directions[:, None, :]
    occupied = inside & occupancy.lookup(points)
    count = occupied.sum(dim=1)
    table = torch.zeros(
        len(rays), int(count.max()) if total else 0, dtype=torch.long, device=start.device
    )
    ray, segment = torch.nonzero(occupied, as_tuple=True)
    rank = occupied.cumsum(dim=1)[ray, segment] - 1
    table[ray, rank] = segment
    return start, table, count


def segment_samples(
    rays: Rays,
    start: torch.Tensor,
    segments: torch.Tensor,
    segment_valid: torch.Tensor,
    segment_length: float,
    samples_per_segment: int,
    jitter: torch.Tensor | float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Stratified distances inside the given segments: (t [R, G*K], valid [R, G*K]).

    `jitter` in [0, 1) is the offset of each sample inside its stratum ([R, G] tensor, or 0.5 for the
    stratum centres used when rendering).
    """
    step = segment_length / samples_per_segment
    offsets = torch.arange(samples_per_segment, device=segments.device, dtype=torch.float32)
    offsets = offsets + jitter[..., None] if torch.is_tensor(jitter) else offsets + jitter
    t = start[:, None, None] + segments[..., None] * segment_length + offsets * step
    valid = segment_valid[..., None] & (t < rays.far[:, None, None])
    return t.flatten(1), valid.flatten(1)
