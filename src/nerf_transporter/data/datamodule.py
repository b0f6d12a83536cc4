"""RavensDataModule: demonstration episodes -> training batches shaped per method (docs/interfaces.md).

The model's `input_kind` picks the batch layout:

- `imagery` (mira): the top-down pick view, the positive place view followed by K negative views
  (other grid views of the same scene: uniform, or weighted towards the positive with
  `negative_view_scale`), pixels and the rotation bin;
- `heightmap` (transporter_se2/se3, form2fit): the fused RGB-D heightmap, pixels, rotation bin and
  the place z, roll and pitch;
- `state` (gt_state_mlp): the state vector and the oracle pick and place poses.

Every random choice of a sample (SE(2) and colour augmentation, negative views) comes from a seed the sampler
draws from (seed, epoch, position), so batches do not depend on the number of worker processes,
and a fit resumed from a checkpoint saved mid-epoch trains on the rest of that epoch's samples, as
the uninterrupted fit would have.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from nerf_transporter import geometry as g
from nerf_transporter.data import episode as ep
from nerf_transporter.data.augment import (
    AUGMENT_DISTRIBUTIONS,
    Se2Transform,
    augment_view_action,
    identity_transform,
    sample_colour_jitter,
    sample_transform,
)
from nerf_transporter.data.generate import GenerationConfig, action_from_meta, generate_dataset
from nerf_transporter.data.heightmap import heightmap_from_rgbd
from nerf_transporter.data.labels import (
    ViewAction,
    continuous_pixel,
    labels_from_view_action,
    to_view_frames,
)
from nerf_transporter.data.observation import INPUT_KINDS, reference_imagery_options
from nerf_transporter.data.preprocess import network_input
from nerf_transporter.data.seeds import seed_loader
from nerf_transporter.sim import TASKS, cameras

FILES_PER_KIND = {"imagery": ["imagery"], "heightmap": ["rgbd"], "state": []}
# How the negative views of an imagery sample move under SE(2) augmentation: "shared", by the
# transform of the pick and place views; "own", each by a transform of its own (MIRA's recipe).
NEGATIVE_TRANSFORMS = ("shared", "own")


@dataclass
class Demo:
    """What a sample needs from one episode, held in memory."""

    seed: int
    view_action: ViewAction  # pick in the top-down view, place in its place view
    pick_view: int = 0  # index of the top-down view among the imagery views
    colour: np.ndarray | None = None  # [V, H, W, 3] (imagery) or [H, W, 3] (heightmap)
    height: np.ndarray | None = None
    state: np.ndarray | None = None
    pick: np.ndarray | None = None  # [7] xyz + quat_xyzw
    place: np.ndarray | None = None


def load_demo(path: Path, input_kind: str, grid: np.ndarray, pixel_size: float) -> Demo:
    """Load one episode for `input_kind`; labels are recomputed from the stored oracle action."""
    episode = ep.load_episode(path, FILES_PER_KIND[input_kind])
    action = action_from_meta(episode.meta)
    seed = int(episode.meta["seed"])
    if input_kind == "imagery":
        imagery = episode.arrays["imagery"]
        view_action = to_view_frames(action, grid)
        if int(imagery["place_view"]) != view_action.place_view:
            raise ep.CorruptEpisodeError(
                f"episode {path.name}: imagery.npz place view {int(imagery['place_view'])} differs "
                f"from the view of its action ({view_action.place_view})"
            )
        return Demo(
            seed,
            view_action,
            pick_view=g.top_down_view_index(grid),
            colour=imagery["colour"],
            height=imagery["height"],
        )
    view_action = to_view_frames(action, np.zeros((1, 2)))
    if input_kind == "heightmap":
        colour, height = heightmap_from_rgbd(episode.arrays["rgbd"], pixel_size)
        return Demo(seed, view_action, colour=colour, height=height)
    return Demo(
        seed,
        view_action,
        state=np.asarray(episode.meta["state"], dtype=np.float32),
        pick=np.concatenate(action["pick"]).astype(np.float32),
        place=np.concatenate(action["place"]).astype(np.float32),
    )


@contextmanager
def regenerate_hint(config: GenerationConfig, count: int, data_dir: Path) -> Iterator[None]:
    """A damaged episode's error (`ep.CorruptEpisodeError`) ending with the command that
    generates its dataset afresh."""
    try:
        yield
    except ep.CorruptEpisodeError as error:
        command = config.command(count, data_dir, regenerate=True)
        raise ep.CorruptEpisodeError(f"{error}; or regenerate the dataset: {command}") from error


class SeededSampler(Sampler):
    """Yields (demo index, sample seed) pairs: `length` per epoch, demos in shuffled passes.

    `resume_at(epoch, start)` makes the next pass over `epoch` begin at position `start` (the
    samples before it were trained on before the fit was interrupted); its length stays `length`.
    """

    def __init__(self, n_demos: int, length: int, seed: int, shuffle: bool = True) -> None:
        self.n_demos, self.length, self.seed, self.shuffle = n_demos, length, seed, shuffle
        self.epoch = 0
        self.resume: tuple[int, int] | None = None

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def resume_at(self, epoch: int, start: int) -> None:
        self.resume = (epoch, start) if 0 < start < self.length else None

    def __len__(self) -> int:
        return self.length

    def __iter__(self) -> Iterator[tuple[int, int]]:
        rng = np.random.default_rng([self.seed, self.epoch if self.shuffle else 0])
        passes = math.ceil(self.length / self.n_demos)
        order = [
            rng.permutation(self.n_demos) if self.shuffle else np.arange(self.n_demos)
            for _ in range(passes)
        ]
        demos = np.concatenate(order)[: self.length]
        seeds = rng.integers(0, 2**63 - 1, size=self.length)
        start = self.resume[1] if self.resume and self.resume[0] == self.epoch else 0
        self.resume = None
        return iter(zip(demos[start:].tolist(), seeds[start:].tolist(), strict=True))


def sample_negative_views(
    rng: np.random.Generator,
    views: np.ndarray,
    positive: int,
    count: int,
    scale: float | None = None,
) -> np.ndarray:
    """`count` distinct views other than `positive`, drawn uniformly or, with `scale` (radians),
    with weight exp(-distance / scale) from the positive's (roll, pitch).

    Near views are the ones `act` confuses with the right one (a neighbour of the grid is 10 deg
    away), so weighting towards them spends the few negatives of a step where they teach most.
    """
    others = np.setdiff1d(np.arange(len(views)), [positive])
    weights = None
    if scale is not None:
        distance = np.linalg.norm(views[others] - views[positive], axis=1)
        weights = np.exp(-distance / scale)
        weights /= weights.sum()
    return rng.choice(others, size=count, replace=False, p=weights)


def apply_each(transforms: list[Se2Transform], images: np.ndarray) -> np.ndarray:
    """Image k of a stack [N, H, W(, C)] moved by transform k."""
    return np.stack([t.apply_image(image) for t, image in zip(transforms, images, strict=True)])


class DemoDataset(Dataset):
    """Samples of one input kind; an item is (demo index, sample seed) from `SeededSampler`."""

    def __init__(
        self,
        demos: list[Demo],
        input_kind: str,
        *,
        pixel_size: float = g.PIXEL_SIZE,
        n_negative_views: int = 0,
        augment: bool = False,
        colour_augment: bool = False,
        n_rotations: int = g.N_ROTATIONS,
        views: np.ndarray | None = None,
        negative_view_scale: float | None = None,
        augment_distribution: str = "uniform",
        negative_transform: str = "shared",
    ) -> None:
        if input_kind not in INPUT_KINDS:
            raise ValueError(f"unknown input_kind {input_kind!r}; valid: {', '.join(INPUT_KINDS)}")
        if input_kind == "imagery" and views is None:
            raise ValueError("imagery samples need the view grid (views=[V, 2] roll, pitch)")
        self.demos, self.input_kind = demos, input_kind
        self.pixel_size, self.n_negative_views = pixel_size, n_negative_views
        self.augment, self.colour_augment, self.n_rotations = augment, colour_augment, n_rotations
        self.views, self.negative_view_scale = views, negative_view_scale
        self.augment_distribution, self.negative_transform = (
            augment_distribution,
            negative_transform,
        )
        self.shape = g.image_shape(pixel_size)

    def __len__(self) -> int:
        return len(self.demos)

    def __getitem__(self, item: tuple[int, int] | int) -> dict[str, torch.Tensor]:
        index, sample_seed = item if isinstance(item, tuple) else (item, item)
        demo = self.demos[index]
        rng = np.random.default_rng(sample_seed)
        if self.input_kind == "state":
            return {
                "state": torch.from_numpy(demo.state),
                "pick": torch.from_numpy(demo.pick),
                "place": torch.from_numpy(demo.place),
            }
        view_action = demo.view_action
        transform = identity_transform(self.shape)
        if self.augment:
            pixels = [
                continuous_pixel(pose[0], self.pixel_size)
                for pose in (view_action.pick, view_action.place)
            ]
            transform = sample_transform(
                rng, self.shape, pixels, distribution=self.augment_distribution
            )
            view_action = augment_view_action(view_action, transform, self.pixel_size)
        labels = labels_from_view_action(view_action, self.pixel_size, self.n_rotations)
        sample = {
            "pick_pixel": torch.tensor(labels.pick_pixel, dtype=torch.long),
            "place_pixel": torch.tensor(labels.place_pixel, dtype=torch.long),
            "rotation_bin": torch.tensor(labels.rotation_bin, dtype=torch.long),
        }
        if self.input_kind == "heightmap":
            sample["image"] = network_input(
                self._recolour(rng, transform.apply_image(demo.colour)),
                transform.apply_image(demo.height),
            )
            sample["place_z"] = torch.tensor(labels.place_z, dtype=torch.float32)
            sample["place_roll"] = torch.tensor(labels.place_roll, dtype=torch.float32)
            sample["place_pitch"] = torch.tensor(labels.place_pitch, dtype=torch.float32)
            return sample
        negatives = sample_negative_views(
            rng, self.views, labels.place_view, self.n_negative_views, self.negative_view_scale
        )
        views = np.concatenate([[demo.pick_view, labels.place_view], negatives]).astype(int)
        transforms = [transform, transform] + [
            sample_transform(rng, self.shape, [], distribution=self.augment_distribution)
            if self.augment and self.negative_transform == "own"
            else transform
            for _ in negatives
        ]
        colour = self._recolour(rng, apply_each(transforms, demo.colour[views]))
        height = apply_each(transforms, demo.height[views])
        images = network_input(colour, height)
        sample["pick_image"] = images[0]
        sample["place_images"] = images[1:]
        return sample

    def _recolour(self, rng: np.random.Generator, colour: np.ndarray) -> np.ndarray:
        """The sample's images with one random colour change (drawn last from the sample's
        generator, so the other draws are those of a run without it), or as they are."""
        return sample_colour_jitter(rng).apply(colour) if self.colour_augment else colour


class RavensDataModule(pl.LightningDataModule):
    """Demonstrations of one task for training (and, optionally, validation losses).

    `prepare_data()` generates missing episodes (the first `n_demos` successful train seeds, and
    `n_val_demos` validation seeds); with `generate_missing=False` a missing dataset is an error
    that prints the `nerf-transporter generate` command to run. `input_kind` is read from the model
    being trained (`trainer.lightning_module.input_kind`), or from the argument without a trainer.
    Closed-loop success rates are measured by the evaluation code: the test dataloader yields the
    first `test_episodes` test seeds, run in `test_setting` (default: `setting`) by `test_workers`
    worker processes (default: one per core available to the process; 1: in the process itself).
    `pin_memory` puts batches in page-locked memory for a faster copy to a GPU (with `num_workers`
    loading them). `augment` moves each training sample's images by a random SE(2) transform,
    drawn from `augment_distribution` ("uniform": any rotation, shifts up to half the image;
    "gaussian": MIRA's N(0, 60 deg) rotation and N(0, 1/6 of the shorter side) shifts,
    `augment.AUGMENT_DISTRIBUTIONS`); an imagery sample's negative views move with the pick and
    place views (`negative_transform` "shared") or each by a transform of its own ("own", MIRA's).
    `colour_augment` also changes their colour at random (hue turned around the whole circle,
    saturation and value scaled; `augment.sample_colour_jitter`), for image methods tested on
    object colours no training seed has (hanging-disks).

    Methods that do not use imagery (heightmap, state) read any existing dataset of the task with
    the configured imagery, else one generated with `imagery="oracle"`: their inputs (RGB-D, state)
    and the oracle actions are the same for a seed whatever the imagery.
    """

    def __init__(
        self,
        task: str,
        setting: str = "normal",
        n_demos: int = 10,
        data_dir: str = "data",
        batch_size: int = 1,
        num_workers: int = 0,
        imagery: str = "nerf",
        pixel_size: float = g.PIXEL_SIZE,
        n_negative_views: int = 4,
        negative_view_scale: float | None = None,
        augment: bool = True,
        colour_augment: bool = False,
        augment_distribution: str = "uniform",
        negative_transform: str = "shared",
        generate_missing: bool = True,
        seed: int = 0,
        input_kind: str | None = None,
        n_val_demos: int = 0,
        samples_per_epoch: int | None = None,
        n_rotations: int = g.N_ROTATIONS,
        nerf_views: int = 30,
        nerf_image_size: tuple[int, int] = cameras.IMAGE_SIZE,
        imagery_config: dict[str, Any] | None = None,
        generate_workers: int = 1,
        test_episodes: int = 100,
        test_setting: str | None = None,
        test_workers: int | None = None,
        pin_memory: bool = False,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if n_demos < 1:
            raise ValueError(f"n_demos must be >= 1, got {n_demos}")
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        if n_rotations < 1:
            raise ValueError(f"n_rotations must be >= 1, got {n_rotations}")
        if test_workers is not None and test_workers < 1:
            raise ValueError(f"test_workers must be >= 1, got {test_workers}")
        n_views = len(g.view_grid(setting))
        if not 0 <= n_negative_views < n_views:
            raise ValueError(f"n_negative_views must be in [0, {n_views - 1}] for {n_views} views")
        if negative_view_scale is not None and negative_view_scale <= 0:
            raise ValueError(
                f"negative_view_scale must be > 0 (radians), got {negative_view_scale}"
            )
        if augment_distribution not in AUGMENT_DISTRIBUTIONS:
            raise ValueError(
                f"augment_distribution must be one of {', '.join(AUGMENT_DISTRIBUTIONS)}, "
                f"got {augment_distribution!r}"
            )
        if negative_transform not in NEGATIVE_TRANSFORMS:
            raise ValueError(
                f"negative_transform must be one of {', '.join(NEGATIVE_TRANSFORMS)}, "
                f"got {negative_transform!r}"
            )
        GenerationConfig(
            task, setting, "train", imagery, pixel_size, nerf_views, tuple(nerf_image_size)
        )  # validates
        self.task, self.setting, self.n_demos = task, setting, n_demos
        self.data_dir, self.batch_size, self.num_workers = Path(data_dir), batch_size, num_workers
        self.imagery, self.pixel_size = imagery, pixel_size
        self.n_negative_views, self.augment = n_negative_views, augment
        self.colour_augment = colour_augment
        self.augment_distribution, self.negative_transform = (
            augment_distribution,
            negative_transform,
        )
        self.negative_view_scale = negative_view_scale
        self.generate_missing, self.seed, self.input_kind = generate_missing, seed, input_kind
        self.n_val_demos, self.samples_per_epoch, self.n_rotations = (
            n_val_demos,
            samples_per_epoch,
            n_rotations,
        )
        self.nerf_views, self.nerf_image_size = nerf_views, tuple(nerf_image_size)
        self.generate_workers = generate_workers
        self._set_imagery_config(dict(imagery_config or {}))
        self.test_episodes, self.test_setting = test_episodes, test_setting
        self.test_workers = test_workers
        self.pin_memory = pin_memory
        self.train_dataset: DemoDataset | None = None
        self.val_dataset: DemoDataset | None = None

    # -- configuration -------------------------------------------------------------------------

    @property
    def state_dim(self) -> int:
        """Length of the task's state vector (`gt_state_mlp`'s input), known without loading data."""
        return TASKS[self.task].state_dim()

    def resolve_input_kind(self) -> str:
        trainer = getattr(self, "trainer", None)
        module = getattr(trainer, "lightning_module", None) if trainer is not None else None
        kind = getattr(module, "input_kind", None) or self.input_kind
        if kind not in INPUT_KINDS:
            raise ValueError(
                f"input_kind {kind!r}: train with a method that sets `input_kind`, or pass "
                f"input_kind= one of {', '.join(INPUT_KINDS)}"
            )
        return kind

    def _set_imagery_config(self, imagery_config: dict[str, Any]) -> None:
        """Set the NeRF imagery's settings, and name them in the hyper-parameters a checkpoint
        keeps as the changes from the reference imagery (with the given settings), so that the
        checkpoint is read back on the imagery it was trained on (`load_from_checkpoint`)."""
        self.imagery_config = imagery_config
        changes = self.generation_config("train").scene.imagery_changes()
        self.hparams["imagery_config"] = {**imagery_config, **changes}

    @staticmethod
    def trained_imagery(saved: dict[str, Any] | None) -> dict[str, Any]:
        """The NeRF imagery settings a checkpoint was trained on, from the `imagery_config` its
        datamodule hyper-parameters hold, whatever this code's defaults: the reference imagery
        (`reference_imagery_options`) with the settings they name (a checkpoint written before
        checkpoints named them names only those its config set, and was trained on the
        reference)."""
        return reference_imagery_options() | dict(saved or {})

    @classmethod
    def load_from_checkpoint(cls, checkpoint_path: Any, *args: Any, **kwargs: Any) -> Any:
        """Lightning's, on the NeRF imagery the checkpoint was trained on (`trained_imagery`)."""
        datamodule = super().load_from_checkpoint(checkpoint_path, *args, **kwargs)
        datamodule._set_imagery_config(cls.trained_imagery(datamodule.imagery_config))
        return datamodule

    def generation_config(self, split: str, imagery: str | None = None) -> GenerationConfig:
        return GenerationConfig(
            task=self.task,
            setting=self.setting,
            split=split,
            imagery=imagery or self.imagery,
            pixel_size=self.pixel_size,
            nerf_views=self.nerf_views,
            nerf_image_size=self.nerf_image_size,
            imagery_options=self.imagery_config,
        )

    def _wanted(self) -> list[tuple[str, int]]:
        """(split, episodes) the running stage reads: fit both, validate validation, test none."""
        trainer = getattr(self, "trainer", None)
        stage = trainer.state.fn if trainer is not None and trainer.state.fn is not None else "fit"
        wanted = [("train", self.n_demos)] if stage == "fit" else []
        if stage in ("fit", "validate") and self.n_val_demos > 0:
            wanted.append(("validation", self.n_val_demos))
        return wanted

    def _config_for(self, split: str, count: int, input_kind: str) -> GenerationConfig:
        """The dataset a split is read from (non-imagery methods fall back to oracle imagery)."""
        config = self.generation_config(split)
        if input_kind == "imagery" or config.imagery == "oracle":
            return config
        if len(ep.list_episodes(self.data_dir / config.dataset_name())) >= count:
            return config
        return self.generation_config(split, imagery="oracle")

    # -- LightningDataModule -------------------------------------------------------------------

    def prepare_data(self) -> None:
        if not self.generate_missing:
            return
        input_kind = self.resolve_input_kind()
        for split, count in self._wanted():
            config = self._config_for(split, count, input_kind)
            with regenerate_hint(config, count, self.data_dir):
                generate_dataset(config, count, self.data_dir, workers=self.generate_workers)

    def load_split(self, split: str, count: int, input_kind: str) -> list[Demo]:
        """The first `count` episodes of a split (each file checked against its checksum: see
        `ep.load_episode`), or an error saying how to generate them."""
        config = self._config_for(split, count, input_kind)
        with regenerate_hint(config, count, self.data_dir):
            return self._load_demos(config, split, count, input_kind)

    def _load_demos(
        self, config: GenerationConfig, split: str, count: int, input_kind: str
    ) -> list[Demo]:
        dataset_dir = self.data_dir / config.dataset_name()
        ep.check_dataset_config(
            dataset_dir, config.description(), config.command(count, self.data_dir, regenerate=True)
        )
        refs = ep.list_episodes(dataset_dir)[:count]
        if len(refs) < count:
            reason = (
                "generate_missing is off"
                if not self.generate_missing
                else "prepare_data() did not run"
            )
            raise FileNotFoundError(
                f"{dataset_dir} holds {len(refs)} of the {count} {split} episodes needed and {reason}. "
                f"Generate them with:\n  {config.command(count, self.data_dir)}"
            )
        return [load_demo(ref.path, input_kind, config.grid, self.pixel_size) for ref in refs]

    def setup(self, stage: str | None = None) -> None:
        input_kind = self.resolve_input_kind()
        options = {
            "pixel_size": self.pixel_size,
            "n_negative_views": self.n_negative_views,
            "n_rotations": self.n_rotations,
            "views": g.view_grid(self.setting),
            "negative_view_scale": self.negative_view_scale,
        }
        if stage in (None, "fit") and self.train_dataset is None:
            demos = self.load_split("train", self.n_demos, input_kind)
            self.train_dataset = DemoDataset(
                demos,
                input_kind,
                augment=self.augment,
                colour_augment=self.colour_augment,
                augment_distribution=self.augment_distribution,
                negative_transform=self.negative_transform,
                **options,
            )
        if stage in (None, "fit", "validate") and self.n_val_demos > 0 and self.val_dataset is None:
            demos = self.load_split("validation", self.n_val_demos, input_kind)
            self.val_dataset = DemoDataset(demos, input_kind, augment=False, **options)

    def _loader(self, dataset: DemoDataset, sampler: SeededSampler) -> DataLoader:
        return DataLoader(
            dataset,
            batch_size=self.batch_size,
            sampler=sampler,
            num_workers=self.num_workers,
            persistent_workers=self.num_workers > 0,
            pin_memory=self.pin_memory,
        )

    def train_dataloader(self) -> DataLoader:
        if self.train_dataset is None:
            self.setup("fit")
        length = self.samples_per_epoch or len(self.train_dataset)
        sampler = SeededSampler(len(self.train_dataset), length, self.seed)
        if self.trainer is not None:  # a resumed fit: skip the epoch's batches already trained
            trained = self.trainer.fit_loop.epoch_loop.batch_progress.current.processed
            sampler.resume_at(self.trainer.current_epoch, trained * self.batch_size)
        return self._loader(self.train_dataset, sampler)

    def val_dataloader(self) -> DataLoader | list:
        if self.n_val_demos == 0:
            return []
        if self.val_dataset is None:
            self.setup("validate")
        n = len(self.val_dataset)
        return self._loader(self.val_dataset, SeededSampler(n, n, self.seed, shuffle=False))

    def test_dataloader(self) -> DataLoader:
        """Seeds of the closed-loop test episodes (`lightning test`, see evaluation/testing.py)."""
        return seed_loader("test", self.test_episodes)
