"""Fit a radiance field to posed RGB images and render the orthographic view grid from it."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from tqdm.auto import tqdm

from nerf_transporter import geometry
from nerf_transporter.imagery.fields import (
    DenseGridField,
    FloorMap,
    HashGridField,
    RadianceField,
    grid_nodes,
)
from nerf_transporter.imagery.losses import binary_entropy, distortion
from nerf_transporter.imagery.rays import (
    Rays,
    depth_to_height,
    orthographic_rays,
    perspective_rays,
)
from nerf_transporter.imagery.render import (
    COLOUR_ESTIMATES,
    DEPTH_ESTIMATES,
    MarchSettings,
    render_rays,
    render_rays_train,
)
from nerf_transporter.imagery.samplers import OccupancyGrid

FIELD_TYPES = ("dense", "hash")
COLOUR_INITS = ("grey", "table")  # ImageryConfig.colour_init
# ImageryConfig fields that change how the fitted field is rendered, not the fit: imagery that
# differs in these alone is rendered from one fit (`data.observation.scene_imageries`)
RENDER_OPTIONS = ("depth", "colour")


class NonFiniteLossError(FloatingPointError):
    """The fitting loss became NaN or infinite."""


@dataclass
class ImageryConfig:
    """Settings of the radiance-field fit and of the orthographic rendering."""

    field: str = (
        "dense"  # "dense" (voxel grid; default on CPU and GPU) or "hash" (instant-NGP style)
    )
    device: str = "auto"  # "auto": CUDA when available, else CPU (render_batch follows the device)
    seed: int = 0
    iterations: int = 400
    batch_rays: int = 4096
    image_downscale: int = 2  # fit on images average-pooled by this factor
    learning_rate: float = 0.1  # dense colour grid
    density_learning_rate: float = 0.3  # dense density grid (opaque needs raw values of ~+8)
    floor_learning_rate: float = (
        0.01  # low, so objects are explained by density, not painted on the floor
    )
    hash_learning_rate: float = 0.01
    hash_levels: int = 16
    hash_log2_table: int = 19
    voxel_size: float = 0.003125
    colour_downscale: int = 2  # colour grid at 1 / this of the density resolution
    stage_scales: tuple[int, ...] = (4, 2, 1)  # coarse-to-fine: grid at 1 / scale of the finest
    stage_starts: tuple[float, ...] = (
        0.0,
        0.25,
        0.55,
    )  # fraction of iterations where a stage starts
    initial_thickness: float = 0.002  # optical thickness per voxel at initialisation
    floor_cell: float = 0.003125  # floor colour map resolution (m)
    occupancy_cell: int = 4  # occupancy cell edge in voxels
    occupancy_threshold: float = 0.01  # optical thickness per voxel below which a cell is empty
    occupancy_interval: int = 16
    occupancy_warmup: int = 32
    samples_per_segment: int = 4  # sample spacing = occupancy cell edge / samples_per_segment
    sparsity_weight: float = 0.0003  # times the opacity summed along a ray, averaged over rays
    binary_weight: float = 0.1  # times the entropy of the floor's share of each ray
    binary_ramp: float = 0.25  # fraction of the iterations over which binary_weight ramps up
    floor_smoothness_weight: float = 0.01  # times the mean squared colour step of the floor map
    # times mip-NeRF 360's distortion loss (metres; `losses.distortion`): each ray's weight in one
    # short stretch. 0: off (the default; docs/imagery.md, "The distortion loss")
    distortion_weight: float = 0.0
    # the dense field's starting colour: "table": the captures' median colour, the floor map's
    # start, so that density costs the colour loss nothing until the field's colour is learned; or
    # "grey" (0.5; the reference imagery's): under it, objects brighter than grey on a bright table,
    # a white or pink disk, are driven out of the field before their colour is, and left painted on
    # the floor (docs/imagery.md, "The default imagery")
    colour_init: str = "table"
    # the rendered views' height: "expected" (the rays' mean termination distance) or "median"
    # (where a ray's accumulated opacity reaches one half; `render.median_depth`). Rendering only:
    # the fit is the same either way
    depth: str = "expected"
    # the rendered views' colour: "expected" (the rays' weighted mean colour) or "median" (the
    # field's colour where the median depth lies; `render.median_colour`). Rendering only
    colour: str = "expected"
    final_learning_rate_factor: float = 0.1  # exponential decay of the learning rate to this factor
    pixel_size: float = geometry.PIXEL_SIZE  # of the rendered orthographic views
    render_batch: int = (
        0  # rays per rendering call, views batched; 0: per device (see render_rays_per_call)
    )
    threads: int | None = None  # torch CPU threads (None: leave torch's default)
    progress: bool = True

    def __post_init__(self) -> None:
        if self.field not in FIELD_TYPES:
            raise ValueError(f"unknown field type {self.field!r}; expected one of {FIELD_TYPES}")
        if self.depth not in DEPTH_ESTIMATES:
            raise ValueError(f"unknown depth {self.depth!r}; expected one of {DEPTH_ESTIMATES}")
        if self.colour not in COLOUR_ESTIMATES:
            raise ValueError(f"unknown colour {self.colour!r}; expected one of {COLOUR_ESTIMATES}")
        if self.colour_init not in COLOUR_INITS:
            raise ValueError(
                f"unknown colour_init {self.colour_init!r}; expected one of {COLOUR_INITS}"
            )
        if len(self.stage_scales) != len(self.stage_starts):
            raise ValueError("stage_scales and stage_starts must have the same length")
        for name in ("iterations", "batch_rays", "image_downscale", "samples_per_segment"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.render_batch < 0:
            raise ValueError(f"render_batch must be >= 0, got {self.render_batch}")

    @property
    def voxels(self) -> tuple[int, int, int]:
        multiple = max(self.stage_scales) * max(self.colour_downscale, self.occupancy_cell)
        return grid_nodes(self.voxel_size, multiple)

    def march_settings(self) -> MarchSettings:
        return MarchSettings(
            segment_length=self.voxel_size * self.occupancy_cell,
            samples_per_segment=self.samples_per_segment,
        )

    def render_rays_per_call(self, device: torch.device) -> int:
        """`render_batch`, or when 0 the device's default.

        CPU: 1 << 16 rays (about one view; larger batches only cost memory). CUDA: 1 << 19 rays
        (about ten views per call, a few GiB), since small batches leave the GPU waiting on Python.
        """
        if self.render_batch > 0:
            return self.render_batch
        return 1 << 19 if device.type == "cuda" else 1 << 16


class FittedScene(nn.Module):
    """What `fit_scene` returns: the radiance field, the floor map and the occupancy grid."""

    def __init__(self, field: RadianceField, floor: FloorMap, occupancy: OccupancyGrid) -> None:
        super().__init__()
        self.field = field
        self.floor = floor
        self.occupancy = occupancy

    @property
    def device(self) -> torch.device:
        return self.floor.image.device

    def render(
        self, rays: Rays, settings: MarchSettings, depth: str = "expected", colour: str = "expected"
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return render_rays(self.field, self.floor, self.occupancy, rays, settings, depth, colour)


def resolve_device(name: str = "auto") -> torch.device:
    """'auto' -> CUDA when available, else CPU; anything else is passed to torch.device."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def make_field(config: ImageryConfig, table_colour: torch.Tensor | None = None) -> RadianceField:
    """The radiance field the config names, at its first coarse-to-fine stage; with
    `colour_init="table"` it starts at `table_colour` (RGB in (0, 1))."""
    initial_colour = table_colour if config.colour_init == "table" else None
    if config.field == "hash":
        voxels = config.voxels
        occupancy = tuple(v // config.occupancy_cell * 2 for v in voxels)
        return HashGridField(
            config.voxel_size,
            initial_thickness=config.initial_thickness,
            occupancy_voxels=occupancy,
            initial_colour=initial_colour,
        )
    return DenseGridField(
        config.voxels,
        config.voxel_size,
        colour_downscale=config.colour_downscale,
        initial_thickness=config.initial_thickness,
        initial_scale=config.stage_scales[0],
        initial_colour=initial_colour,
    )


def _check_inputs(images: np.ndarray, intrinsics: np.ndarray, cam_to_world: np.ndarray) -> None:
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images must be [N, H, W, 3], got shape {images.shape}")
    count = images.shape[0]
    if intrinsics.shape != (count, 3, 3):
        raise ValueError(f"intrinsics must be [{count}, 3, 3], got {intrinsics.shape}")
    if cam_to_world.shape != (count, 4, 4):
        raise ValueError(f"cam_to_world must be [{count}, 4, 4], got {cam_to_world.shape}")
    for name, array in (
        ("images", images),
        ("intrinsics", intrinsics),
        ("cam_to_world", cam_to_world),
    ):
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{name} contain non-finite values")


def _prepare_images(
    images: np.ndarray, intrinsics: np.ndarray, downscale: int, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor]:
    """Images as float [N, H, W, 3] in [0, 1] average-pooled by `downscale`, with matching intrinsics."""
    pixels = torch.as_tensor(images, device=device)
    pixels = pixels.float() / 255.0 if pixels.dtype == torch.uint8 else pixels.float()
    k = torch.as_tensor(intrinsics, dtype=torch.float32, device=device).clone()
    if downscale > 1:
        pixels = F.avg_pool2d(pixels.permute(0, 3, 1, 2), downscale).permute(0, 2, 3, 1)
        # a pooled pixel u covers full-resolution centres downscale*u .. downscale*u + downscale - 1
        k[:, :2, :] /= downscale
        k[:, :2, 2] -= (downscale - 1) / (2 * downscale)
    return pixels.contiguous(), k


def _floor_rays(
    intrinsics: torch.Tensor, cam_to_world: torch.Tensor, shape: tuple[int, int, int]
) -> torch.Tensor:
    """Flat indices (camera, row, col) of the pixels whose rays leave the box through its floor.

    Only these rays are fitted: a ray that leaves through a side wall sees things outside the box
    that the field cannot explain.
    """
    count, height, width = shape
    rows, cols = torch.meshgrid(
        torch.arange(height, device=intrinsics.device),
        torch.arange(width, device=intrinsics.device),
        indexing="ij",
    )
    rows, cols = rows.reshape(-1), cols.reshape(-1)
    chosen = []
    for camera in range(count):
        ids = torch.full_like(rows, camera)
        rays = perspective_rays(intrinsics, cam_to_world, ids, rows, cols)
        flat = torch.nonzero(rays.exits_through_floor)[:, 0]
        chosen.append(flat + camera * height * width)
    return torch.cat(chosen)


def _stage_at(config: ImageryConfig, iteration: int) -> int:
    progress = iteration / config.iterations
    stage = 0
    for index, start in enumerate(config.stage_starts):
        if progress >= start:
            stage = index
    return config.stage_scales[stage]


def _optimizer(
    config: ImageryConfig, field: RadianceField, floor: FloorMap
) -> torch.optim.Optimizer:
    """Fused Adam (one pass over each grid; several times faster than the default on CPU)."""
    groups = [{"params": list(floor.parameters()), "lr": config.floor_learning_rate}]
    if isinstance(field, DenseGridField):
        groups.append({"params": [field.density_grid], "lr": config.density_learning_rate})
        groups.append({"params": [field.colour_grid], "lr": config.learning_rate})
    else:
        groups.append({"params": list(field.parameters()), "lr": config.hash_learning_rate})
    eps = 1e-15 if config.field == "hash" else 1e-8
    try:
        optimizer = torch.optim.Adam(groups, eps=eps, fused=True)
    except RuntimeError:  # fused Adam needs torch >= 2.4 on CPU
        optimizer = torch.optim.Adam(groups, eps=eps)
    for group in optimizer.param_groups:
        group["initial_lr"] = group["lr"]
    return optimizer


def fit_scene(
    images: np.ndarray,
    intrinsics: np.ndarray,
    cam_to_world: np.ndarray,
    config: ImageryConfig | None = None,
) -> FittedScene:
    """Fit a radiance field to N posed RGB images (uint8 [N, H, W, 3], OpenCV cameras).

    Fits with gradients whatever the caller's grad mode: `trainer.test` runs under
    `torch.inference_mode()`, and closed-loop test episodes fit their NeRFs inside it.
    Raises NonFiniteLossError (and returns nothing) if the loss stops being finite.
    """
    with torch.inference_mode(False), torch.enable_grad():
        return _fit_scene(images, intrinsics, cam_to_world, config or ImageryConfig())


def _fit_scene(
    images: np.ndarray, intrinsics: np.ndarray, cam_to_world: np.ndarray, config: ImageryConfig
) -> FittedScene:
    images, intrinsics, cam_to_world = (np.asarray(a) for a in (images, intrinsics, cam_to_world))
    _check_inputs(images, intrinsics, cam_to_world)
    if config.threads:
        torch.set_num_threads(config.threads)
    device = resolve_device(config.device)
    torch.manual_seed(config.seed)
    generator = torch.Generator(device=device).manual_seed(config.seed)

    pixels, k = _prepare_images(images, intrinsics, config.image_downscale, device)
    poses = torch.as_tensor(cam_to_world, dtype=torch.float32, device=device)
    count, height, width, _ = pixels.shape
    candidates = _floor_rays(k, poses, (count, height, width))
    if candidates.numel() == 0:
        raise ValueError("no camera ray crosses the workspace box down to its floor")
    flat_pixels = pixels.view(-1, 3)

    table_colour = (
        flat_pixels[candidates[:: max(1, candidates.numel() // 65536)]].median(dim=0).values.cpu()
    )
    field_ = make_field(config, table_colour).to(device)
    floor = FloorMap(config.floor_cell, table_colour).to(device)
    occupancy = OccupancyGrid(
        tuple(v // config.occupancy_cell for v in config.voxels), device=device
    )
    settings = config.march_settings()
    threshold = config.occupancy_threshold / config.voxel_size
    optimizer = _optimizer(config, field_, floor)

    progress = tqdm(
        range(config.iterations), desc="fit radiance field", disable=not config.progress
    )
    for iteration in progress:
        if field_.set_stage(_stage_at(config, iteration)):
            optimizer = _optimizer(config, field_, floor)
        if iteration >= config.occupancy_warmup and iteration % config.occupancy_interval == 0:
            occupancy.update(field_.density_lattice(), threshold)
        pick = torch.randint(
            candidates.numel(), (config.batch_rays,), generator=generator, device=device
        )
        flat = candidates[pick]
        camera = flat // (height * width)
        rows = (flat // width) % height
        cols = flat % width
        rays = perspective_rays(k, poses, camera, rows, cols)
        output = render_rays_train(field_, floor, occupancy, rays, settings, generator)
        ramp = min(1.0, iteration / max(1.0, config.binary_ramp * config.iterations))
        colour_loss = F.mse_loss(output.colour, flat_pixels[flat])
        sparsity = output.alpha.sum() / len(rays)
        loss = (
            colour_loss
            + config.sparsity_weight * sparsity
            + config.binary_weight * ramp * binary_entropy(output.floor_weight)
            + config.floor_smoothness_weight * floor.smoothness()
        )
        if config.distortion_weight:
            loss = loss + config.distortion_weight * distortion(output, settings.step, rays.floor)
        if not torch.isfinite(loss):
            raise NonFiniteLossError(
                f"fitting loss became {float(loss.detach())} at iteration {iteration}; the fit was stopped "
                "and nothing was written (lower learning_rate or check the input images and poses)"
            )
        decay = config.final_learning_rate_factor ** (iteration / config.iterations)
        for group in optimizer.param_groups:
            group["lr"] = group["initial_lr"] * decay
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if iteration % 20 == 0:
            psnr = -10.0 * math.log10(max(float(colour_loss.detach()), 1e-10))
            progress.set_postfix(psnr=f"{psnr:.1f}", occupied=f"{occupancy.fraction:.2f}")
    occupancy.update(field_.density_lattice(), threshold)
    return FittedScene(field_, floor, occupancy)


def render_views(
    scene: FittedScene, views: np.ndarray, config: ImageryConfig | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Orthographic colour (uint8 [V, H, W, 3]) and height (float32 [V, H, W]) of views [V, 2] (roll, pitch).

    The rays of all views are rendered together, `config.render_rays_per_call` at a time.
    """
    config = config or ImageryConfig()
    views = np.asarray(views, dtype=float).reshape(-1, 2)
    rows, cols = geometry.image_shape(config.pixel_size)
    if len(views) == 0:
        return np.empty((0, rows, cols, 3), np.uint8), np.empty((0, rows, cols), np.float32)
    settings = config.march_settings()
    per_view = [
        orthographic_rays(roll, pitch, config.pixel_size, device=scene.device)
        for roll, pitch in views
    ]
    rays = Rays(**{f.name: torch.cat([getattr(r, f.name) for r in per_view]) for f in fields(Rays)})
    batch = config.render_rays_per_call(scene.device)
    colour_parts, height_parts = [], []
    for start in range(0, len(rays), batch):
        colour, depth = scene.render(
            rays[start : start + batch], settings, config.depth, config.colour
        )
        colour_parts.append(colour.clamp(0.0, 1.0).mul(255.0).round().to(torch.uint8))
        height_parts.append(depth_to_height(depth))
    colours = torch.cat(colour_parts).view(len(views), rows, cols, 3).cpu().numpy()
    heights = torch.cat(height_parts).view(len(views), rows, cols).cpu().numpy()
    return colours, heights
