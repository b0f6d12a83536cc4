"""Transport (place) model: rotated pick crops as kernels, cross-correlated with the place image(s).

Rotation bin k is the angle theta_k = 2 pi k / n (`geometry.bin_to_angle`) of (place yaw - pick yaw).
Kernel k is computed from the pick crop with its content rotated by +theta_k about the pick pixel
(counter-clockwise about world z: x towards y, i.e. columns towards rows), so it shows the held object
as it will look once the gripper has turned by theta_k. Rotating the pick scene by +m bins therefore
shifts the logits by -m bins (tested).

Correlation runs in the Fourier domain: 36 kernels of 64 x 64 over a 320 x 160 image cost a few FFTs
instead of ~20 GMAC of direct convolution; the backward pass is hand-written FFT correlations too.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from nerf_transporter import geometry as g
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


def fast_fft_length(n: int) -> int:
    """Smallest length >= n with no prime factor above 5 (pocketfft's fast sizes)."""
    while True:
        rest = n
        for prime in (2, 3, 5):
            while rest % prime == 0:
                rest //= prime
        if rest == 1:
            return n
        n += 1


def fft_shape(image_shape: tuple[int, int], crop_size: int) -> tuple[int, int]:
    """FFT domain for a centred correlation with no wrap-around: image + half a kernel, rounded up
    to fast FFT lengths."""
    half = crop_size // 2
    return fast_fft_length(image_shape[0] + half), fast_fft_length(image_shape[1] + half)


def _spectrum(x: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """rfft2 of real maps [..., h, w] zero-padded to `shape`: the short rows first, then columns."""
    return torch.fft.fft(torch.fft.rfft(x, n=shape[1]), n=shape[0], dim=-2)


def _conj_spectrum(x: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """The complex conjugate of `_spectrum`, computed directly (unnormalised inverse transforms)."""
    rows = torch.fft.ihfft(x, n=shape[1], norm="forward")
    return torch.fft.ifft(rows, n=shape[0], dim=-2, norm="forward")


def _circular_slice(x: torch.Tensor, dim: int, start: int, size: int) -> torch.Tensor:
    """Entries start, start + 1, ..., start + size - 1 (mod the length) of x along `dim`."""
    length = x.shape[dim]
    start %= length
    if start + size <= length:
        return x.narrow(dim, start, size)
    head = x.narrow(dim, start, length - start)
    return torch.cat([head, x.narrow(dim, 0, size - head.shape[dim])], dim)


def _window(
    spectrum: torch.Tensor, shape: tuple[int, int], offset: int, size: tuple[int, int]
) -> torch.Tensor:
    """Real maps [..., size] at circular positions offset + (0 .. size - 1) of irfft2(spectrum).

    The column transform runs only on the kept rows.
    """
    rows = _circular_slice(torch.fft.ifft(spectrum, dim=-2), -2, offset, size[0])
    return _circular_slice(torch.fft.irfft(rows, n=shape[1]), -1, offset, size[1])


def kernel_spectrum(kernels: torch.Tensor, image_shape: tuple[int, int]) -> torch.Tensor:
    """Conjugated Fourier transform of kernels [B, R, C, k, k] on the FFT domain of `image_shape`
    images: what `correlate_spectrum` multiplies the query spectrum by."""
    return _conj_spectrum(kernels, fft_shape(image_shape, kernels.shape[-1]))


def _correlate_spectra(query_f: torch.Tensor, kernel_f: torch.Tensor) -> torch.Tensor:
    """Channel sum of query spectra [B, V, C, h, w] times conjugated kernel spectra [B, R, C, h, w]
    -> [B, V, R, h, w]."""
    product = query_f[:, :, None, 0] * kernel_f[:, None, :, 0]
    for channel in range(1, query_f.shape[2]):  # few channels: a loop beats a complex einsum
        product += query_f[:, :, None, channel] * kernel_f[:, None, :, channel]
    return product


def correlate_spectrum(query: torch.Tensor, kernel_f: torch.Tensor, crop_size: int) -> torch.Tensor:
    """Centred cross-correlation of query maps [B, V, C, H, W] with `kernel_spectrum` output ->
    [B, V, R, H, W].

    out[y, x] = sum_{c,u,v} query[c, y + u - k/2, x + v - k/2] * kernel[c, u, v], with the query zero
    outside the image: kernel pixel (k/2, k/2), the crop's centre, lands on (y, x).
    """
    height, width = query.shape[-2:]
    shape = fft_shape((height, width), crop_size)
    product = _correlate_spectra(_spectrum(query, shape), kernel_f)
    # Circular index (y - k/2) mod Hp holds output row y.
    return _window(product, shape, -(crop_size // 2), (height, width))


class _CrossCorrelation(torch.autograd.Function):
    """`correlate_spectrum` with a hand-written backward: the gradients are themselves FFT
    correlations on the same domain, which costs a fraction of autograd through the transforms."""

    @staticmethod
    def forward(
        ctx: torch.autograd.function.FunctionCtx, query: torch.Tensor, kernels: torch.Tensor
    ) -> torch.Tensor:
        height, width = query.shape[-2:]
        crop_size = kernels.shape[-1]
        shape = fft_shape((height, width), crop_size)
        query_f = _spectrum(query, shape)
        kernel_f = _conj_spectrum(kernels, shape)
        ctx.save_for_backward(query_f, kernel_f)
        ctx.geometry = shape, crop_size, (height, width)
        product = _correlate_spectra(query_f, kernel_f)
        return _window(product, shape, -(crop_size // 2), (height, width))

    @staticmethod
    def backward(
        ctx: torch.autograd.function.FunctionCtx, grad: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        query_f, kernel_f = ctx.saved_tensors
        shape, crop_size, image_shape = ctx.geometry
        half = crop_size // 2
        grad_f = _conj_spectrum(grad, shape)  # [B, V, R, h, w], output pixel (y, x) at (y, x)
        # d query[c, Y] = sum_{r,u} grad[r, Y + k/2 - u] kernel[r, c, u]: a convolution.
        query_grad_f = grad_f[:, :, 0, None] * kernel_f[:, None, 0]
        for rotation in range(1, kernel_f.shape[1]):  # beats einsum's transposing copies
            query_grad_f += grad_f[:, :, rotation, None] * kernel_f[:, None, rotation]
        query_grad_f = query_grad_f.conj()
        query_grad = _window(query_grad_f, shape, half, image_shape)
        # d kernel[r, c, u] = sum_{v,y} grad[v, r, y] query[v, c, y + u - k/2]: a correlation.
        kernel_grad_f = grad_f[:, 0, :, None] * query_f[:, 0, None]
        for view in range(1, query_f.shape[1]):
            kernel_grad_f += grad_f[:, view, :, None] * query_f[:, view, None]
        kernel_grad = _window(kernel_grad_f, shape, -half, (crop_size, crop_size))
        return query_grad, kernel_grad


def cross_correlate(query: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """Centred cross-correlation, summed over channels: query [B, V, C, H, W], kernels
    [B, R, C, k, k] -> [B, V, R, H, W] (see `correlate_spectrum`).

    At least float32: the FFTs have no bfloat16 kernels, and under CUDA's bf16 autocast
    (configs/gpu/bf16.yaml) the features arrive in bfloat16 (CPU autocast casts FFTs itself).
    """
    dtype = torch.promote_types(torch.promote_types(query.dtype, kernels.dtype), torch.float32)
    return _CrossCorrelation.apply(query.to(dtype), kernels.to(dtype))


class Transport(nn.Module):
    """Two ResNet43 streams: key on rotated pick crops, query on the place image(s).

    The query map is zero outside the image, so placements up to half a crop beyond the image
    border still correlate (as with Transporter's zero-padded place image, at 40% less cost).
    """

    def __init__(
        self,
        in_channels: int = 6,
        feature_channels: int = 3,
        n_rotations: int = g.N_ROTATIONS,
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
