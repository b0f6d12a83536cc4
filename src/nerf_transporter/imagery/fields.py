"""Radiance fields over the workspace box: a dense voxel grid (the default) and a hash grid.

The dense grid is the default on every device: on an H100 the plain-PyTorch hash grid fitted
slower and worse than the dense grid (its per-level gathers and MLPs cost more than one trilinear
lookup), so it stays an option only.

A field maps world points [N, 3] to a density (optical thickness per metre, [N]) and a colour
([N, 3] in [0, 1]); colour is view-independent (the simulated surfaces are diffuse). The floor map
is the opaque table at z = 0: a learned 2-D colour image, clamped at its border outside the box.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import torch
import torch.nn.functional as F
from torch import nn

from nerf_transporter import geometry

BOX_EXTENT = tuple(float(e) for e in geometry.BOUNDS[:, 1] - geometry.BOUNDS[:, 0])


def _normalise(points: torch.Tensor) -> torch.Tensor:
    """World xyz -> grid_sample coordinates in [-1, 1] (x, y, z order)."""
    low = torch.as_tensor(geometry.BOUNDS[:, 0], dtype=points.dtype, device=points.device)
    extent = torch.as_tensor(BOX_EXTENT, dtype=points.dtype, device=points.device)
    return 2.0 * (points - low) / extent - 1.0


def sample_grid(grid: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Trilinear interpolation of a [1, C, D, H, W] grid at world points [N, 3] -> [N, C].

    On CPU the points are split into one batch per thread: PyTorch parallelises 3-D grid_sample
    over the batch dimension only.
    """
    coords = _normalise(points)
    count = coords.shape[0]
    splits = torch.get_num_threads() if coords.device.type == "cpu" and count >= 8192 else 1
    padded = math.ceil(count / splits) * splits
    if padded != count:
        coords = torch.cat([coords, coords.new_zeros(padded - count, 3)])
    batch = coords.view(splits, 1, 1, padded // splits, 3)
    values = F.grid_sample(
        grid.expand(splits, -1, -1, -1, -1), batch, align_corners=True, padding_mode="border"
    )
    channels = grid.shape[1]
    return values.view(splits, channels, -1).permute(0, 2, 1).reshape(padded, channels)[:count]


def colour_logits(colour: torch.Tensor) -> torch.Tensor:
    """The raw values whose sigmoid is `colour` (RGB, kept 0.02 from 0 and 1 to stay trainable)."""
    return torch.logit(colour.float().clamp(0.02, 0.98))


def thickness_shift(initial_thickness: float) -> float:
    """Bias so that softplus(0 + shift) equals the initial optical thickness per voxel."""
    return math.log(math.expm1(initial_thickness))


class RadianceField(nn.Module, ABC):
    """Density and colour of the scene inside the workspace box."""

    @abstractmethod
    def density(self, points: torch.Tensor) -> torch.Tensor:
        """Optical thickness per metre at world points [N, 3] -> [N]."""

    @abstractmethod
    def colour(self, points: torch.Tensor) -> torch.Tensor:
        """RGB in [0, 1] at world points [N, 3] -> [N, 3]."""

    @abstractmethod
    def density_lattice(self) -> torch.Tensor:
        """Density on a regular lattice of nodes spanning the box, [Z, Y, X] (for occupancy)."""

    def set_stage(self, scale: int) -> bool:
        """Switch to the resolution 1/scale of the finest; True if parameters were replaced."""
        return False


def grid_nodes(voxel_size: float, multiple: int) -> tuple[int, int, int]:
    """Voxel counts (x, y, z) of the finest grid: extent / voxel_size rounded up to a multiple."""
    return tuple(int(math.ceil(e / voxel_size / multiple) * multiple) for e in BOX_EXTENT)


class DenseGridField(RadianceField):
    """Dense voxel grids (density at full resolution, colour at 1/colour_downscale), trilinear.

    Coarse-to-fine: `set_stage(s)` resamples both grids to 1/s of the finest resolution.
    """

    def __init__(
        self,
        voxels: tuple[int, int, int],
        voxel_size: float,
        colour_downscale: int = 2,
        initial_thickness: float = 0.05,
        initial_scale: int = 1,
        initial_colour: torch.Tensor | None = None,
    ) -> None:
        """`initial_colour` (RGB in (0, 1)) fills the colour grid; default grey (0.5)."""
        super().__init__()
        self.voxels = voxels
        self.voxel_size = voxel_size
        self.colour_downscale = colour_downscale
        self.shift = thickness_shift(initial_thickness)
        self.scale = initial_scale
        self.density_grid = nn.Parameter(torch.zeros(self._shape(initial_scale, 1)))
        start = torch.zeros(1, 3, 1, 1, 1)
        if initial_colour is not None:
            start = colour_logits(initial_colour).view(1, 3, 1, 1, 1)
        shape = self._shape(initial_scale, 3, colour_downscale)
        self.colour_grid = nn.Parameter(start.expand(shape).clone())

    def _shape(self, scale: int, channels: int, extra: int = 1) -> tuple[int, ...]:
        nx, ny, nz = (max(2, v // (scale * extra)) + 1 for v in self.voxels)
        return (1, channels, nz, ny, nx)

    def density(self, points: torch.Tensor) -> torch.Tensor:
        raw = sample_grid(self.density_grid, points)[:, 0]
        return F.softplus(raw + self.shift) / self.voxel_size

    def colour(self, points: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(sample_grid(self.colour_grid, points))

    def density_lattice(self) -> torch.Tensor:
        return F.softplus(self.density_grid.detach()[0, 0] + self.shift) / self.voxel_size

    def set_stage(self, scale: int) -> bool:
        if scale == self.scale:
            return False
        self.scale = scale
        for name, channels, extra in (
            ("density_grid", 1, 1),
            ("colour_grid", 3, self.colour_downscale),
        ):
            old = getattr(self, name).detach()
            size = self._shape(scale, channels, extra)[2:]
            new = F.interpolate(old, size=size, mode="trilinear", align_corners=True)
            setattr(self, name, nn.Parameter(new.contiguous()))
        return True


class HashGridField(RadianceField):
    """Multi-resolution hash encoding (instant-NGP style) with small MLP heads, in plain PyTorch.

    An option only: slower than the dense grid on CPU (far) and on an H100, and no more accurate.
    """

    PRIMES = (1, 2654435761, 805459861)

    def __init__(
        self,
        voxel_size: float,
        levels: int = 16,
        features: int = 2,
        log2_table: int = 19,
        coarsest_cell: float = 0.25,
        hidden: int = 64,
        initial_thickness: float = 0.05,
        occupancy_voxels: tuple[int, int, int] = (80, 160, 48),
        initial_colour: torch.Tensor | None = None,
    ) -> None:
        """`initial_colour` (RGB in (0, 1)): the colour head starts at it everywhere (its last
        layer's weights zero, its bias the colour's logits); default: the head's random start."""
        super().__init__()
        self.voxel_size = voxel_size
        self.table_size = 2**log2_table
        growth = (coarsest_cell / voxel_size) ** (1.0 / max(1, levels - 1))
        self.cells = [coarsest_cell / growth**level for level in range(levels)]
        self.tables = nn.Parameter(
            torch.empty(levels, self.table_size, features).uniform_(-1e-4, 1e-4)
        )
        self.shift = thickness_shift(initial_thickness)
        self.occupancy_voxels = occupancy_voxels
        self.geometry_net = nn.Sequential(
            nn.Linear(levels * features, hidden), nn.ReLU(), nn.Linear(hidden, 16)
        )
        self.colour_net = nn.Sequential(nn.Linear(15, hidden), nn.ReLU(), nn.Linear(hidden, 3))
        # start from the same uniform, nearly empty volume as the dense grid
        nn.init.zeros_(self.geometry_net[-1].weight)
        nn.init.zeros_(self.geometry_net[-1].bias)
        if initial_colour is not None:
            with torch.no_grad():
                nn.init.zeros_(self.colour_net[-1].weight)
                self.colour_net[-1].bias.copy_(colour_logits(initial_colour))

    def _encode(self, points: torch.Tensor) -> torch.Tensor:
        low = torch.as_tensor(geometry.BOUNDS[:, 0], dtype=points.dtype, device=points.device)
        local = points - low
        corners = torch.tensor(
            [[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)], device=points.device
        )
        primes = torch.tensor(self.PRIMES, device=points.device)
        encoded = []
        for level, cell in enumerate(self.cells):
            scaled = local / cell
            base = scaled.floor()
            frac = scaled - base
            index = base.long()[:, None, :] + corners[None]
            dims = torch.tensor(
                [int(math.ceil(e / cell)) + 1 for e in BOX_EXTENT], device=points.device
            )
            if int(dims.prod()) <= self.table_size:
                index = index.clamp(min=torch.zeros_like(dims), max=dims - 1)
                slot = index[..., 0] + dims[0] * (index[..., 1] + dims[1] * index[..., 2])
            else:
                hashed = index * primes
                slot = (hashed[..., 0] ^ hashed[..., 1] ^ hashed[..., 2]) % self.table_size
            weights = torch.where(
                corners[None].bool(), frac[:, None, :], 1.0 - frac[:, None, :]
            ).prod(-1)
            values = (
                self.tables[level]
                .index_select(0, slot.reshape(-1))
                .view(*slot.shape, self.tables.shape[-1])
            )
            encoded.append((weights[..., None] * values).sum(1))
        return torch.cat(encoded, dim=-1)

    def _geometry(self, points: torch.Tensor) -> torch.Tensor:
        return self.geometry_net(self._encode(points))

    def density(self, points: torch.Tensor) -> torch.Tensor:
        return F.softplus(self._geometry(points)[:, 0] + self.shift) / self.voxel_size

    def colour(self, points: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.colour_net(self._geometry(points)[:, 1:]))

    @torch.no_grad()
    def density_lattice(self) -> torch.Tensor:
        nx, ny, nz = (v + 1 for v in self.occupancy_voxels)
        device = self.tables.device
        axes = [
            torch.linspace(float(lo), float(hi), n, device=device)
            for (lo, hi), n in zip(geometry.BOUNDS, (nx, ny, nz), strict=True)
        ]
        zs, ys, xs = torch.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
        points = torch.stack([xs, ys, zs], dim=-1).reshape(-1, 3)
        values = torch.cat([self.density(chunk) for chunk in points.split(1 << 18)])
        return values.view(nz, ny, nx)


class FloorMap(nn.Module):
    """Opaque floor at z = 0: a learned colour image over the box footprint, border-clamped outside."""

    def __init__(self, cell_size: float, colour: torch.Tensor | None = None) -> None:
        """`colour` (RGB in (0, 1)) initialises the whole map, e.g. to the table's median colour."""
        super().__init__()
        nx, ny = (int(round(e / cell_size)) + 1 for e in BOX_EXTENT[:2])
        start = torch.zeros(1, 3, 1, 1)
        if colour is not None:
            start = colour_logits(colour).view(1, 3, 1, 1)
        self.image = nn.Parameter(start.expand(1, 3, ny, nx).clone())

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """RGB in [0, 1] of the floor below world points [N, 3] (their x, y) -> [N, 3]."""
        coords = _normalise(points)[:, :2].view(1, 1, -1, 2)
        values = F.grid_sample(self.image, coords, align_corners=True, padding_mode="border")
        return torch.sigmoid(values[0, :, 0].T)

    def smoothness(self) -> torch.Tensor:
        """Mean squared colour difference between neighbouring texels (a total-variation prior)."""
        colour = torch.sigmoid(self.image)
        rows = (colour[..., 1:, :] - colour[..., :-1, :]).square().mean()
        cols = (colour[..., :, 1:] - colour[..., :, :-1]).square().mean()
        return rows + cols
