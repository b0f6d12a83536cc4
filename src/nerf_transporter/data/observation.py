"""What a method sees of a scene, built from its capture: one builder for generation and evaluation.

A `SceneSpec` fixes everything the observation of a seed depends on besides the seed: the world
(task, setting), the cameras (`nerf` rig size), the pixel size and how imagery is built. Both the
generator's `GenerationConfig` (data/generate.py) and the evaluator's `EvaluationSpec`
(evaluation/rollout.py) are built around one, so the data a method is trained on and the scenes it
is judged on are made the same way (docs/conventions.md, "Data layout on disk" and "Evaluation
protocol"):

- imagery (the imagery methods): the simulator's orthographic view grid (`oracle`) or a radiance
  field fitted to the `nerf` rig's RGB images and rendered over that grid (`nerf`), rounded as
  episodes store it (colour uint8, height float16);
- the fused RGB-D heightmap (the heightmap methods);
- the state vector (GT-State MLP).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from nerf_transporter import geometry as g
from nerf_transporter.data.heightmap import heightmap_from_rgbd
from nerf_transporter.sim import SETTINGS, TASKS, cameras

if TYPE_CHECKING:
    from nerf_transporter.imagery import ImageryConfig

INPUT_KINDS = ("imagery", "heightmap", "state")  # what a method reads (its `input_kind`)
IMAGERY_KINDS = ("nerf", "oracle")
# ImageryConfig fields that change how fast imagery is built, not what it is
IMAGERY_RUNTIME_FIELDS = ("device", "progress", "threads", "render_batch")
# imagery settings that enter a description only where they differ from these values (every
# dataset, cache entry and cell was built under them before the setting existed), so that those
# keep their identities
IMAGERY_OPTIONS_BY_DEFAULT = {
    "colour_init": "grey",
    "distortion_weight": 0.0,
    "depth": "expected",
    "colour": "expected",
}
# The NeRF imagery every dataset, cache entry and cell was built with until the table-colour start
# became the default (the description of `ImageryConfig()` as it stood, pixel size apart): the
# reference that names imagery changes (`SceneSpec.imagery_changes`). A dataset of other settings
# is named with a hash of them, and a cell's protocol holds them (`imagery_changes`), so a changed
# default of `ImageryConfig` makes new datasets and fits of their own, beside those of the
# reference, and a checkpoint is read back on the imagery it was trained on
# (`RavensDataModule.load_from_checkpoint`). Never edit it: the data, cells and checkpoints built
# so far are named relative to it.
REFERENCE_IMAGERY: dict[str, Any] = {
    "field": "dense",
    "seed": 0,
    "iterations": 400,
    "batch_rays": 4096,
    "image_downscale": 2,
    "learning_rate": 0.1,
    "density_learning_rate": 0.3,
    "floor_learning_rate": 0.01,
    "hash_learning_rate": 0.01,
    "hash_levels": 16,
    "hash_log2_table": 19,
    "voxel_size": 0.003125,
    "colour_downscale": 2,
    "stage_scales": (4, 2, 1),
    "stage_starts": (0.0, 0.25, 0.55),
    "initial_thickness": 0.002,
    "floor_cell": 0.003125,
    "occupancy_cell": 4,
    "occupancy_threshold": 0.01,
    "occupancy_interval": 16,
    "occupancy_warmup": 32,
    "samples_per_segment": 4,
    "sparsity_weight": 0.003,
    "binary_weight": 0.1,
    "binary_ramp": 0.25,
    "floor_smoothness_weight": 0.01,
    "final_learning_rate_factor": 0.1,
}


def reference_imagery_options() -> dict[str, Any]:
    """The reference imagery as `ImageryConfig` fields: `REFERENCE_IMAGERY` with the settings added
    since at the values it was built under (`IMAGERY_OPTIONS_BY_DEFAULT`)."""
    return {**REFERENCE_IMAGERY, **IMAGERY_OPTIONS_BY_DEFAULT}


@dataclass(frozen=True)
class SceneSpec:
    """The scene of a seed and how it is observed: task, setting, imagery kind, pixel size of every
    image a method sees, the `nerf` rig (`nerf_views` cameras of `nerf_image_size`) and
    `imagery_options` (`ImageryConfig` fields for `nerf` imagery; the pixel size is the scene's)."""

    task: str
    setting: str = "normal"
    imagery: str = "nerf"
    pixel_size: float = g.PIXEL_SIZE
    nerf_views: int = 30
    nerf_image_size: tuple[int, int] = cameras.IMAGE_SIZE
    imagery_options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r}; valid tasks: {', '.join(sorted(TASKS))}")
        if self.setting not in SETTINGS:
            raise ValueError(
                f"unknown setting {self.setting!r}; valid settings: {', '.join(SETTINGS)}"
            )
        if not (math.isfinite(self.pixel_size) and self.pixel_size > 0) or (
            min(g.image_shape(self.pixel_size)) < 1
        ):
            raise ValueError(
                f"--pixel-size must be > 0 and smaller than the workspace (metres per pixel), "
                f"got {self.pixel_size!r}"
            )
        if self.nerf_views < 0:
            raise ValueError(f"--nerf-views must be >= 0, got {self.nerf_views}")
        if self.imagery not in IMAGERY_KINDS:
            raise ValueError(
                f"unknown imagery {self.imagery!r}; valid choices: {', '.join(IMAGERY_KINDS)}"
            )
        if self.imagery == "nerf" and self.nerf_views < 1:
            raise ValueError("--imagery nerf needs --nerf-views >= 1")
        options_pixel_size = self.imagery_options.get("pixel_size", self.pixel_size)
        if not math.isclose(options_pixel_size, self.pixel_size):
            raise ValueError(
                f"imagery config pixel_size {options_pixel_size} differs from the pixel_size "
                f"{self.pixel_size}"
            )
        object.__setattr__(self, "nerf_image_size", tuple(int(v) for v in self.nerf_image_size))
        if len(self.nerf_image_size) != 2 or min(self.nerf_image_size) < 1:
            size = "x".join(map(str, self.nerf_image_size))
            raise ValueError(f"--nerf-image-size must be ROWSxCOLS, each >= 1, got {size}")
        object.__setattr__(self, "imagery_options", dict(self.imagery_options))
        if self.imagery == "nerf":
            self.imagery_config()  # validates the options

    @property
    def grid(self) -> np.ndarray:
        """The view grid of the setting [V, 2] (roll, pitch)."""
        return g.view_grid(self.setting)

    def imagery_config(self) -> ImageryConfig:
        """The imagery package's config for `nerf` imagery (at the scene's pixel size)."""
        from nerf_transporter.imagery import ImageryConfig

        return ImageryConfig(
            **{**self.imagery_options, "pixel_size": self.pixel_size, "progress": False}
        )

    def rendered_with(self, options: dict[str, Any]) -> SceneSpec:
        """This scene's `nerf` imagery rendered with other rendering options (`RENDER_OPTIONS`
        fields, e.g. `{"depth": "median"}`) from the same fit; ValueError for any other option or
        imagery."""
        from nerf_transporter.imagery import RENDER_OPTIONS

        if self.imagery != "nerf":
            raise ValueError(
                f"rendering options set NeRF imagery's; this is {self.imagery} imagery"
            )
        fit_options = sorted(set(options) - set(RENDER_OPTIONS))
        if fit_options:
            raise ValueError(
                f"{', '.join(fit_options)} changes the fit, not its rendering (rendering "
                f"options: {', '.join(RENDER_OPTIONS)})"
            )
        return dataclasses.replace(self, imagery_options={**self.imagery_options, **options})

    def imagery_changes(self) -> dict[str, Any]:
        """The entries of `imagery_description` that differ from `REFERENCE_IMAGERY` (the pixel
        size apart: the scene's own), tuples as the lists JSON gives back; {} for oracle imagery."""
        if self.imagery != "nerf":
            return {}
        return {
            key: list(value) if isinstance(value, tuple) else value
            for key, value in self.imagery_description().items()
            if key != "pixel_size"
            and (key not in REFERENCE_IMAGERY or REFERENCE_IMAGERY[key] != value)
        }

    def imagery_description(self) -> dict[str, Any]:
        """The `nerf` imagery config without the fields that only change how fast it is built, nor
        those of `IMAGERY_OPTIONS_BY_DEFAULT` at their default."""
        config = dataclasses.asdict(self.imagery_config())
        return {
            key: value
            for key, value in config.items()
            if key not in IMAGERY_RUNTIME_FIELDS
            and not (key in IMAGERY_OPTIONS_BY_DEFAULT and value == IMAGERY_OPTIONS_BY_DEFAULT[key])
        }


class SceneConfig:
    """Base of a config built around a `SceneSpec` (its `scene`): the scene's public attributes
    read through it (`config.task` is `config.scene.task`, `config.grid` its `grid`)."""

    scene: SceneSpec

    def __getattr__(self, name: str) -> Any:
        if name == "scene" or name.startswith("_"):  # unset (e.g. while unpickling), or private
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return getattr(self.scene, name)


def oracle_views(env: Any, views: np.ndarray, pixel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's ground truth of `views` [K, 2] (roll, pitch) as it stands: colour
    [K, H, W, 3] and height [K, H, W]."""
    rendered = [
        env.render_orthographic(roll, pitch, pixel_size=pixel_size) for roll, pitch in views
    ]
    return np.stack([view[0] for view in rendered]), np.stack([view[1] for view in rendered])


def fitted_views(
    capture: dict[str, np.ndarray], views: np.ndarray, configs: Sequence[ImageryConfig]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """A radiance field fitted to the `nerf` rig's `capture` (rgb, intrinsics, cam_to_world) with
    the first of `configs`, rendered over `views` with each of them (configs that differ in their
    rendering options only, `imagery.RENDER_OPTIONS`): colour [V, H, W, 3] and height [V, H, W]."""
    from nerf_transporter.imagery import RENDER_OPTIONS, fit_scene, render_views

    ignored = set(RENDER_OPTIONS) | set(IMAGERY_RUNTIME_FIELDS)
    fit_settings = [
        {key: value for key, value in dataclasses.asdict(config).items() if key not in ignored}
        for config in configs
    ]
    if any(settings != fit_settings[0] for settings in fit_settings):
        raise ValueError(
            "imagery rendered from one fit may differ in its rendering options only "
            f"({', '.join(RENDER_OPTIONS)})"
        )
    scene = fit_scene(capture["rgb"], capture["intrinsics"], capture["cam_to_world"], configs[0])
    return [render_views(scene, views, config) for config in configs]


def scene_imageries(
    scenes: Sequence[SceneSpec], env: Any, capture: dict
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The imagery of the scene in `env` just captured (`capture`, the observation of reset), as
    each of `scenes` builds it: the simulator's views for `oracle` imagery, a field fitted once and
    rendered per scene for `nerf` (scenes that differ in their rendering options only,
    `SceneSpec.rendered_with`)."""
    first = scenes[0]
    if first.imagery == "oracle":
        if len(scenes) > 1:
            raise ValueError("oracle imagery is rendered one way only")
        return [oracle_views(env, first.grid, first.pixel_size)]
    return fitted_views(capture["nerf"], first.grid, [scene.imagery_config() for scene in scenes])


def scene_imagery(scene: SceneSpec, env: Any, capture: dict) -> tuple[np.ndarray, np.ndarray]:
    """The imagery of the scene in `env` just captured, as `scene` builds it (`scene_imageries`)."""
    return scene_imageries([scene], env, capture)[0]


def rounded(colour: np.ndarray, height: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Views as episodes store them: colour uint8, height float16."""
    return np.asarray(colour).astype(np.uint8), np.asarray(height).astype(np.float16)


def imagery_observations(
    scenes: Sequence[SceneSpec], env: Any, capture: dict
) -> list[dict[str, np.ndarray]]:
    """The imagery an imagery method acts on, as each of `scenes` builds it (`scene_imageries`):
    the views of the grid with the rounding of the training episodes (height then as float32), and
    the grid."""
    imageries = (rounded(*views) for views in scene_imageries(scenes, env, capture))
    return [
        {"colour": colour, "height": height.astype(np.float32), "views": scene.grid}
        for scene, (colour, height) in zip(scenes, imageries, strict=True)
    ]


def imagery_observation(scene: SceneSpec, env: Any, capture: dict) -> dict[str, np.ndarray]:
    """The imagery an imagery method acts on, as `scene` builds it (`imagery_observations`)."""
    return imagery_observations([scene], env, capture)[0]


def observation(
    input_kind: str,
    scene: SceneSpec,
    env: Any,
    capture: dict,
    imagery: dict[str, np.ndarray] | None = None,
) -> dict[str, Any]:
    """What a method of `input_kind` sees of the scene just captured: the state vector, the fused
    RGB-D heightmap, or the imagery (`imagery` when given, e.g. from a cache, else built)."""
    if input_kind == "state":
        return {"state": capture["state"]}
    if input_kind == "heightmap":
        colour, height = heightmap_from_rgbd(capture["rgbd"], scene.pixel_size)
        return {"heightmap": {"colour": colour, "height": height}}
    if input_kind != "imagery":
        raise ValueError(f"unknown input_kind {input_kind!r}; valid: {', '.join(INPUT_KINDS)}")
    if imagery is None:
        imagery = imagery_observation(scene, env, capture)
    return {"imagery": imagery}
