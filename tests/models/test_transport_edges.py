"""The transport at its edges (the mutants of docs/mutation.md that test_models.py let live):
FFT lengths, an odd FFT width, odd crops, the label of a view other than the first, what a
Transport builds and keeps in its state."""

import pytest
import torch
import torch.nn.functional as F

from nerf_transporter.models.transport import (
    Transport,
    correlate_spectrum,
    fast_fft_length,
    fft_shape,
    kernel_spectrum,
    placement_cross_entropy,
    rotated_crops,
)

pytestmark = pytest.mark.usefixtures("one_thread")


def test_fft_lengths_are_the_smallest_with_no_prime_factor_above_5():
    lengths = {1: 1, 7: 8, 11: 12, 13: 15, 14: 15, 17: 18, 64: 64, 97: 100, 161: 162, 337: 360}
    assert {n: fast_fft_length(n) for n in lengths} == lengths


def test_correlation_on_an_odd_fft_width_is_the_direct_one():
    """11 + 4 columns: the FFT domain is 15 wide (odd), where an inverse real FFT must be told
    its length."""
    generator = torch.Generator().manual_seed(0)
    query = torch.randn(1, 1, 2, 11, 11, generator=generator, dtype=torch.float64)
    kernels = torch.randn(1, 3, 2, 8, 8, generator=generator, dtype=torch.float64)
    assert fft_shape((11, 11), 8) == (15, 15)
    logits = correlate_spectrum(query, kernel_spectrum(kernels, (11, 11)), 8)
    # out[y, x] = sum query[y + u - 4, x + v - 4] kernel[u, v]: pad 4 before, 3 after
    direct = F.conv2d(F.pad(query[0], (4, 3, 4, 3)), kernels[0])
    assert torch.allclose(logits[0], direct, atol=1e-9)


def test_an_odd_crop_is_centred_on_its_pixel():
    image = torch.arange(1.0, 50.0).view(1, 1, 7, 7)
    crops = rotated_crops(image, torch.tensor([[3, 3]]), torch.tensor([0.0]), 5)
    assert torch.allclose(crops[0, 0, 0], image[0, 0, 1:6, 1:6], atol=1e-4)


def test_the_place_label_may_lie_in_any_view():
    """The label (view 1, bin 2, row 3, col 1) of logits [1, 2, 4, 5, 6]: its own flat index."""
    logits = torch.randn(1, 2, 4, 5, 6, generator=torch.Generator().manual_seed(0))
    loss = placement_cross_entropy(logits, torch.tensor([[3, 1]]), torch.tensor([2]), view=1)
    expected = -torch.log_softmax(logits.flatten(1), 1)[0, ((1 * 4 + 2) * 5 + 3) * 6 + 1]
    assert float(loss) == pytest.approx(float(expected))


def test_a_transport_builds_what_it_is_asked_for_and_keeps_only_its_weights():
    transport = Transport(in_channels=6, feature_channels=5, n_rotations=4, crop_size=8, width=4)
    image = torch.zeros(1, 6, 16, 8)
    assert transport.query(image).shape == (1, 5, 16, 8)
    assert transport.kernels(image, torch.tensor([[8, 4]])).shape == (1, 4, 5, 8, 8)
    wider = Transport(in_channels=6, feature_channels=5, n_rotations=4, crop_size=8, width=8)
    weights = sum(p.numel() for p in transport.parameters())
    assert weights < sum(p.numel() for p in wider.parameters())
    for network in (transport.key, transport.query):
        assert network.stem.out_channels == 4
    # the rotation angles are rebuilt, not stored: the shipped policies' state has no such key
    assert not [key for key in transport.state_dict() if "angles" in key]
    with pytest.raises(ValueError, match="crop_size must be even, got 7"):
        Transport(crop_size=7)
