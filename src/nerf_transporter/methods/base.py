"""The interface every method shares: training on DataModule batches, logging, and `act`."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import lightning as L
import numpy as np
import torch
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_warn

from nerf_transporter import geometry as g
from nerf_transporter.data.preprocess import (
    COLOUR_MEAN,
    COLOUR_STD,
    empty_pixel_input,
    network_input,
)
from nerf_transporter.drawing import heatmap_picture
from nerf_transporter.models import Attention, ResNet43_8s, Transport, pixel_cross_entropy
from nerf_transporter.models.graphs import (
    graph_training_passes,
    to_channels_last,
    ungraph_training_passes,
)
from nerf_transporter.models.transport import placement_cross_entropy, unravel_argmax

Batch = dict[str, torch.Tensor]
Action = dict[str, g.Pose]
# FCN width of the image methods: at 16 a full-size mira training step takes 0.5 s with 2 threads on
# the 2-core development CPU (docs/measurements.md, "Speed"); Transporter networks use 64 (set
# model.init_args.width on a GPU).
DEFAULT_WIDTH = 16
FULL_PRECISION = ("32-true", "32")  # trainer.precision values without autocast


class Method(L.LightningModule):
    """Base class of the methods; LightningCLI's `model` is a subclass of it.

    Subclasses set `name` (the log folder) and `input_kind` (what the DataModule feeds them), and
    implement `losses(batch)` (a dict with the total under "loss"), `act(observation)` and, for
    image-based methods, `heatmaps(batch)` (affordance maps of the first sample, logged as images).
    A method is judged from outside: `trainer.test` batches are episode seeds, which a callback
    plays closed loop (`lightning test` adds it).
    """

    name: ClassVar[str]
    input_kind: ClassVar[str]
    # arguments a checkpoint is tested under as the test's config names them (`lightning test`)
    test_time_options: ClassVar[tuple[str, ...]] = ()

    def __init__(self, lr: float = 1e-4, log_images_every_n_steps: int = 250) -> None:
        super().__init__()
        if not (math.isfinite(lr) and lr > 0):
            raise ValueError(f"lr must be positive, got {lr}")
        self.lr = lr
        self.log_images_every_n_steps = log_images_every_n_steps
        # Lightning collects the arguments of every `__init__` frame of the subclass chain that
        # called this one (each subclass declares its own and passes the rest on as **kwargs)
        self.save_hyperparameters()

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def heatmaps(self, batch: Batch) -> dict[str, torch.Tensor]:
        """name -> RGB image [3, H, W] in [0, 1]; none by default."""
        return {}

    def act(self, observation: dict[str, Any]) -> Action:
        raise NotImplementedError

    def setup(self, stage: str) -> None:
        """Refuse a DataModule whose pixel size or rotation bins differ from the model's (both
        built in Python: `lightning fit` gives the model the data's, see cli.LINKS)."""
        datamodule = getattr(self.trainer, "datamodule", None)
        for key in ("pixel_size", "n_rotations"):
            ours, theirs = getattr(self, key, None), getattr(datamodule, key, None)
            if ours is not None and theirs is not None and ours != theirs:
                raise ValueError(
                    f"model.init_args.{key} is {ours} but data.init_args.{key} is {theirs}; "
                    "set both to the same value"
                )

    def training_step(self, batch: Batch, batch_idx: int) -> torch.Tensor:
        losses = self.losses(batch)
        self._log_losses("train", losses, batch)
        every = self.log_images_every_n_steps
        if every > 0 and self.global_step % every == 0:
            self._log_heatmaps(batch)
        return losses["loss"]

    def validation_step(self, batch: Batch, batch_idx: int) -> None:
        self._log_losses("val", self.losses(batch), batch, sync_dist=True)

    def on_test_start(self) -> None:
        """Refuse a test that would measure nothing: no callback plays the test seeds."""
        if not any(
            getattr(callback, "plays_test_seeds", False) for callback in self.trainer.callbacks
        ):
            raise RuntimeError(
                "trainer.test: the test batches are episode seeds and no callback plays them; add "
                "nerf_transporter.evaluation.testing.ClosedLoopTestCallback() to the Trainer's "
                "callbacks (`lightning test` adds it)"
            )

    def test_step(self, batch: torch.Tensor, batch_idx: int) -> None:
        """Nothing: a test batch holds episode seeds, played by the closed-loop test callback."""

    def configure_optimizers(self) -> torch.optim.Optimizer:
        """Adam; on CUDA its fused kernel (the same update in one launch instead of dozens)."""
        return torch.optim.Adam(self.parameters(), lr=self.lr, fused=self.device.type == "cuda")

    def _log_losses(
        self, stage: str, losses: dict[str, torch.Tensor], batch: Batch, sync_dist: bool = False
    ) -> None:
        batch_size = next(iter(batch.values())).shape[0]
        self.log_dict(
            {f"{stage}/{key}": value.detach() for key, value in losses.items()},
            batch_size=batch_size,
            sync_dist=sync_dist,
            prog_bar=False,
        )
        self.log(
            f"{stage}_loss",
            losses["loss"].detach(),
            batch_size=batch_size,
            prog_bar=True,
            sync_dist=sync_dist,
            logger=False,
        )

    @torch.no_grad()
    def _log_heatmaps(self, batch: Batch) -> None:
        loggers = [lg for lg in self.loggers if isinstance(lg, TensorBoardLogger)]
        if not loggers:
            return
        for name, image in self.heatmaps(batch).items():
            for logger in loggers:
                logger.experiment.add_image(f"heatmap/{name}", image.cpu(), self.global_step)


def overlay(
    image: torch.Tensor, heat: torch.Tensor, label: torch.Tensor | None = None, title: str = ""
) -> torch.Tensor:
    """Network input [6, H, W] and a heatmap [H, W] -> RGB picture [3, H', W'] in [0, 1]: the heat
    in a colormap over the greyed scene, the label pixel (row, col) ringed, a colour bar
    (`drawing.heatmap_picture`)."""
    colour = (image[:3] * COLOUR_STD + COLOUR_MEAN).clamp(0, 1).mul(255).byte()
    picture = heatmap_picture(
        colour.permute(1, 2, 0).cpu().numpy(),
        heat.detach().float().cpu().numpy(),
        None if label is None else label.tolist(),
        title,
    )
    return torch.from_numpy(picture).permute(2, 0, 1).float() / 255.0


def softmax_map(logits: torch.Tensor) -> torch.Tensor:
    """Softmax over all elements of a logit map, same shape."""
    return logits.flatten().softmax(0).view_as(logits)


def check_image_shape(shape: tuple[int, ...], pixel_size: float, what: str) -> None:
    """ValueError unless an image's (H, W) is the workspace at the model's pixel size."""
    expected = g.image_shape(pixel_size)
    if tuple(shape) != expected:
        raise ValueError(
            f"{what} is {shape[0]}x{shape[1]} pixels, but this model works at pixel_size "
            f"{pixel_size} ({expected[0]}x{expected[1]}); render the observation at that pixel size"
        )


def heightmap_tensors(
    observation: dict[str, Any], pixel_size: float, device: torch.device
) -> tuple[torch.Tensor, np.ndarray]:
    """{"heightmap": {"colour", "height"}} -> (network input [1, 6, H, W], height [H, W] numpy)."""
    if "heightmap" not in observation:
        raise ValueError(f"observation has no 'heightmap' entry (keys: {sorted(observation)})")
    colour = np.asarray(observation["heightmap"]["colour"])
    height = np.asarray(observation["heightmap"]["height"], dtype=np.float32)
    check_image_shape(height.shape, pixel_size, "heightmap")
    return network_input(colour, height)[None].to(device), height


class ImageMethod(Method):
    """A method on top-down images: their pixel size, the rotation bins, crop size and FCN width.

    `lightning fit` takes `pixel_size` and `n_rotations` from the data
    (`experiments/lightning_cli.py` links them). With `cuda_graphs` (configs/gpu/cuda_graphs.yaml), a fit on CUDA runs each ResNet's training
    forward and backward as captured CUDA graphs (`models.graphs`): the same arithmetic in two
    launches instead of hundreds. It does nothing on the CPU or under autocast (bf16-mixed).
    With `square_attention` (configs/recipe/square_attention.yaml) the attention networks (the pick;
    Form2Fit's place too) see their image padded to a square with the augmentation's empty pixels,
    as MIRA's code does (`models.Attention`); off by default, the table's networks so far.
    """

    def __init__(
        self,
        pixel_size: float = g.PIXEL_SIZE,
        n_rotations: int = g.N_ROTATIONS,
        crop_size: int = 64,
        width: int = DEFAULT_WIDTH,
        cuda_graphs: bool = False,
        square_attention: bool = False,
        **kwargs: Any,
    ) -> None:
        if not (math.isfinite(pixel_size) and pixel_size > 0):
            raise ValueError(f"pixel_size must be > 0 (metres per pixel), got {pixel_size}")
        if n_rotations < 1:
            raise ValueError(f"n_rotations must be >= 1, got {n_rotations}")
        super().__init__(**kwargs)
        self.pixel_size = pixel_size
        self.n_rotations = n_rotations
        self.crop_size = crop_size
        self.width = width
        self.cuda_graphs = cuda_graphs
        self.square_attention = square_attention

    def attention_fill(self) -> torch.Tensor | None:
        """The attention networks' `square_fill`: the empty pixel's input, or None (unpadded)."""
        return empty_pixel_input() if self.square_attention else None

    def networks(self) -> list[ResNet43_8s]:
        """The method's fully convolutional networks (what `cuda_graphs` captures)."""
        return [module for module in self.modules() if isinstance(module, ResNet43_8s)]

    def on_train_start(self) -> None:
        if not self.cuda_graphs:
            return
        if self.device.type != "cuda":
            rank_zero_warn(
                f"model.init_args.cuda_graphs: this fit trains on {self.device.type}, not CUDA, "
                "so the networks run eagerly"
            )
            return
        if str(self.trainer.precision) not in FULL_PRECISION:
            rank_zero_warn(
                f"model.init_args.cuda_graphs: under trainer.precision {self.trainer.precision} "
                "(autocast) the networks run eagerly, without CUDA graphs"
            )
        if self.trainer.accumulate_grad_batches > 1:
            raise ValueError(
                "model.init_args.cuda_graphs cannot accumulate gradients (the graphed backward "
                "reuses its gradient buffers); set trainer.accumulate_grad_batches to 1"
            )
        if self.trainer.world_size > 1:
            raise ValueError(
                "model.init_args.cuda_graphs is for a fit on one GPU (its graphs are not captured "
                "for DDP's gradient hooks); drop it or train with trainer.devices 1"
            )
        for net in self.networks():
            to_channels_last(net, self.trainer.optimizers)
            graph_training_passes(net)

    def on_train_end(self) -> None:
        for net in self.networks():
            ungraph_training_passes(net)

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """Refuse a checkpoint trained at another pixel size or number of rotation bins."""
        saved = checkpoint.get("hyper_parameters", {})
        for key in ("pixel_size", "n_rotations"):
            ours = getattr(self, key)
            if key in saved and saved[key] != ours:
                raise ValueError(
                    f"the checkpoint was trained with {key} {saved[key]} but this model is built "
                    f"with {ours} (from data.init_args.{key}); set --data.init_args.{key} {saved[key]}"
                )


class AttentionTransportMethod(ImageMethod):
    """Shared part of `mira`, `transporter_se2` and `transporter_se3`: attention + transport."""

    def __init__(self, feature_channels: int = 3, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.feature_channels = feature_channels
        self.attention = Attention(6, self.width, self.attention_fill())
        self.transport = Transport(
            6, feature_channels, self.n_rotations, self.crop_size, self.width
        )

    def pick_place_losses(
        self, pick_image: torch.Tensor, place_images: torch.Tensor, batch: Batch
    ) -> dict[str, torch.Tensor]:
        """Pick and place cross-entropies; the place label sits in view 0 of `place_images`."""
        pick_loss = pixel_cross_entropy(self.attention(pick_image), batch["pick_pixel"])
        place_logits = self.transport(pick_image, batch["pick_pixel"], place_images)
        place_loss = placement_cross_entropy(
            place_logits, batch["place_pixel"], batch["rotation_bin"]
        )
        return {"loss": pick_loss + place_loss, "pick_loss": pick_loss, "place_loss": place_loss}

    def pick_place_heatmaps(
        self, pick_image: torch.Tensor, place_image: torch.Tensor, batch: Batch
    ) -> dict[str, torch.Tensor]:
        """Pick heatmap and place heatmap (max over rotations) of the first sample, labels ringed."""
        place_logits = self.transport(
            pick_image[:1], batch["pick_pixel"][:1], place_image[:1, None]
        )
        place_heat = softmax_map(place_logits[0, 0]).amax(0)
        return {
            "pick": self.pick_heatmap(pick_image, batch),
            "place": overlay(place_image[0], place_heat, batch["place_pixel"][0], "place"),
        }

    def pick_heatmap(self, pick_image: torch.Tensor, batch: Batch) -> torch.Tensor:
        """The attention's pick probabilities over the first sample, its label ringed."""
        heat = softmax_map(self.attention(pick_image[:1])[0])
        return overlay(pick_image[0], heat, batch["pick_pixel"][0], "pick")

    def predict_pick(self, image: torch.Tensor) -> tuple[int, int]:
        """Argmax pixel (row, col) of the attention logits of one image [1, 6, H, W]."""
        return unravel_argmax(self.attention(image)[0])
