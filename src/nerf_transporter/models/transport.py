"""Transport (place) model: rotated pick crops as kernels, cross-correlated with the place image(s).

Rotation bin k is the angle theta_k = 2 pi k / n (`geometry.bin_to_angle`) of (place yaw - pick yaw).
Kernel k is computed from the pick crop with its content rotated by +theta_k about the pick pixel
(counter-clockwise about world z: x towards y, i.e. columns towards rows), so it shows the held object
as it will look once the gripper has turned by theta_k. Rotating the pick scene by +m bins therefore
shifts the logits by -m bins (tested).

Correlation runs in the Fourier domain: 36 kernels of 64 x 64 over a 320 x 160 image cost a few FFTs
instead of ~20 GMAC of direct convolution.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from nerf_transporter.models.resnet import ResNet43_8s


def bin_angles(n_rotations: int) -> torch.Tensor:
    """Angles of the rotation bins, [n_rotations] (the torch twin of `geometry.bin_to_angle`)."""
    return torch.arange(n_rotations, dtype=torch.float32) * (2 * math.pi / n_rotations)


def rotated_crops(
    images: torch.Tensor, centres: torch.Tensor, angles: torch.Tensor, size: int
) -> torch.Tensor:
    """Square crops around pixels with their content rotated by each angle.

    images [B, C, H, W]; centres [B, 2] (row, col); angles [R] or [B, R] radians -> [B, R, C, size, size].
    Crop pixel (size // 2, size // 2) is the centre pixel. Output offset o samples the input at
    centre + Rot(-angle) o (in (col, row) = (x, y) coordinates), so the content turns by +angle.
    Samples outside the image are zero.
    """
    batch, channels, height, width = images.shape
    angles = angles.to(images).expand(batch, -1) if angles.dim() == 1 else angles.to(images)
    n_rot = angles.shape[1]
    offsets = torch.arange(size, device=images.device, dtype=images.dtype) - size // 2
    off_row, off_col = torch.meshgrid(offsets, offsets, indexing="ij")  # [size, size]
    cos, sin = angles.cos()[..., None, None], angles.sin()[..., None, None]  # [B, R, 1, 1]
    centres = centres.to(images)
    src_col = centres[:, 1, None, None, None] + cos * off_col + sin * off_row
    src_row = centres[:, 0, None, None, None] - sin * off_col + cos * off_row
    grid = torch.stack(
        [src_col * (2.0 / max(width - 1, 1)) - 1.0, src_row * (2.0 / max(height - 1, 1)) - 1.0],
        dim=-1,
    )  # [B, R, size, size, 2]
    crops = F.grid_sample(
        images,
        grid.reshape(batch, n_rot * size, size, 2),
        mode="bilinear",
        padding_mode="zeros",
        align_corners=True,
    )  # [B, C, R * size, size]
    return crops.reshape(batch, channels, n_rot, size, size).transpose(1, 2)


def fft_shape(image_shape: tuple[int, int], crop_size: int) -> tuple[int, int]:
    """Smallest FFT domain for a centred correlation with no wrap-around: image + half a kernel."""
    return image_shape[0] + crop_size // 2, image_shape[1] + crop_size // 2


def kernel_spectrum(kernels: torch.Tensor, image_shape: tuple[int, int]) -> torch.Tensor:
    """Fourier transform of kernels [B, R, C, k, k] on the FFT domain of `image_shape` images."""
    return torch.fft.rfft2(kernels, s=fft_shape(image_shape, kernels.shape[-1]))


def correlate_spectrum(query: torch.Tensor, kernel_f: torch.Tensor, crop_size: int) -> torch.Tensor:
    """Centred cross-correlation of query maps [B, V, C, H, W] with kernel spectra -> [B, V, R, H, W].

    out[y, x] = sum_{c,u,v} query[c, y + u - k/2, x + v - k/2] * kernel[c, u, v], with the query zero
    outside the image: kernel pixel (k/2, k/2), the crop's centre, lands on (y, x).
    """
    height, width = query.shape[-2:]
    shape = fft_shape((height, width), crop_size)
    query_f = torch.fft.rfft2(query, s=shape)
    kernel_f = kernel_f.conj()[:, None]  # [B, 1, R, C, h, w]
    product = query_f[:, :, None, 0] * kernel_f[:, :, :, 0]
    for channel in range(1, query_f.shape[2]):  # few channels: a loop beats a complex einsum
        product += query_f[:, :, None, channel] * kernel_f[:, :, :, channel]
    full = torch.fft.irfft2(product, s=shape)
    # Circular index (y - k/2) mod Hp holds output row y.
    half = crop_size // 2
    return full.roll((half, half), dims=(-2, -1))[..., :height, :width]


def cross_correlate(query: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """Centred cross-correlation, summed over channels: query [B, V, C, H, W], kernels
    [B, R, C, k, k] -> [B, V, R, H, W] (see `correlate_spectrum`)."""
    kernel_f = kernel_spectrum(kernels, query.shape[-2:])
    return correlate_spectrum(query, kernel_f, kernels.shape[-1])


class Transport(nn.Module):
    """Two ResNet43 streams: key on rotated pick crops, query on the place image(s).

    The query map is zero outside the image, so placements up to half a crop beyond the image
    border still correlate (as with Transporter's zero-padded place image, at 40% less cost).
    """

    def __init__(
        self,
        in_channels: int = 6,
        feature_channels: int = 3,
        n_rotations: int = 36,
        crop_size: int = 64,
        width: int = 64,
    ) -> None:
        super().__init__()
        if crop_size % 2:
            raise ValueError(f"crop_size must be even, got {crop_size}")
        self.n_rotations = n_rotations
        self.crop_size = crop_size
        self.key = ResNet43_8s(in_channels, feature_channels, width)
        self.query = ResNet43_8s(in_channels, feature_channels, width)
        self.register_buffer("angles", bin_angles(n_rotations), persistent=False)

    def kernels(self, pick_image: torch.Tensor, pick_pixel: torch.Tensor) -> torch.Tensor:
        """[B, C, H, W], [B, 2] -> kernels [B, R, F, k, k]."""
        crops = rotated_crops(pick_image, pick_pixel, self.angles, self.crop_size)
        features = self.key(crops.flatten(0, 1))
        return features.unflatten(0, crops.shape[:2])

    def query_features(self, place_images: torch.Tensor) -> torch.Tensor:
        """[B, V, C, H, W] -> query maps [B, V, F, H, W]."""
        return self.query(place_images.flatten(0, 1)).unflatten(0, place_images.shape[:2])

    def forward(
        self, pick_image: torch.Tensor, pick_pixel: torch.Tensor, place_images: torch.Tensor
    ) -> torch.Tensor:
        """Place logits [B, V, R, H, W] for place images [B, V, C, H, W] (V = 1 for one view)."""
        return cross_correlate(
            self.query_features(place_images), self.kernels(pick_image, pick_pixel)
        )


def placement_cross_entropy(
    logits: torch.Tensor,
    place_pixel: torch.Tensor,
    rotation_bin: torch.Tensor,
    view: torch.Tensor | int = 0,
) -> torch.Tensor:
    """One softmax over views x rotations x pixels per sample; the label is (view, bin, row, col).

    logits [B, V, R, H, W]; place_pixel [B, 2]; rotation_bin [B]; view [B] or an int -> mean loss.
    """
    _, n_views, n_rot, height, width = logits.shape
    view = torch.as_tensor(view, device=logits.device).expand(logits.shape[0])
    index = ((view * n_rot + rotation_bin) * height + place_pixel[:, 0]) * width + place_pixel[:, 1]
    return F.cross_entropy(logits.flatten(1), index.long())


def unravel_argmax(logits: torch.Tensor) -> tuple[int, ...]:
    """Index tuple of the maximum of one sample's logits (any shape)."""
    flat = int(torch.argmax(logits))
    return tuple(int(i) for i in torch.unravel_index(torch.tensor(flat), logits.shape))
