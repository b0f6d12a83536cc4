import math

import pytest
import torch

from nerf_transporter import geometry as g
from nerf_transporter.data.preprocess import empty_pixel_input
from nerf_transporter.models import (
    Attention,
    PoseRegression,
    ResNet43_8s,
    Transport,
    columns_from_rotation,
    cross_correlate,
    placement_cross_entropy,
    rotated_crops,
    rotation_from_columns,
    unravel_argmax,
)
from nerf_transporter.models.mlp import quat_to_matrix
from nerf_transporter.models.transport import correlate_spectrum, kernel_spectrum

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.mark.parametrize("shape", [(1, 6, 32, 16), (3, 6, 20, 13)])
def test_resnet_output_at_input_resolution(shape):
    net = ResNet43_8s(6, 3, width=4)
    assert net(torch.randn(shape)).shape == (shape[0], 3, *shape[2:])


def test_square_attention_sees_an_images_empty_border_as_its_padding():
    """MIRA's square input: a 32 x 16 image padded to 32 x 32 with the augmentation's empty
    pixel. An image whose outer columns are empty pixels (an augmented one, shifted) gets, on its
    inner columns, the logits of its inner part alone: the border and the padding are one thing,
    and the padding is centred and cropped back."""
    torch.manual_seed(0)
    fill = empty_pixel_input()
    attention = Attention(6, width=4, square_fill=fill).eval()
    inner = torch.randn(1, 6, 32, 8)
    shifted = fill[None, :, None, None].repeat(1, 1, 32, 16)
    shifted[..., 4:12] = inner
    with torch.no_grad():
        whole, alone = attention(shifted), attention(inner)
    assert whole.shape == (1, 32, 16) and alone.shape == (1, 32, 8)
    torch.testing.assert_close(whole[..., 4:12], alone)
    with torch.no_grad():  # unpadded, the same weights see the image's edge, not empty pixels
        unpadded = Attention(6, width=4)
        unpadded.load_state_dict(attention.state_dict())
        assert not torch.allclose(unpadded.eval()(shifted)[..., 4:12], alone, atol=1e-4)


def test_square_attention_refuses_a_fill_of_another_channel_count():
    with pytest.raises(ValueError, match="one value per input channel"):
        Attention(6, width=4, square_fill=torch.zeros(3))


def test_rotated_crop_follows_world_yaw():
    """+90 deg about world z takes +x (columns) to +y (rows): a pixel right of the centre goes below it."""
    image = torch.zeros(1, 1, 21, 21)
    image[0, 0, 10, 13] = 1.0  # 3 columns (+x) right of the centre pixel (10, 10)
    crops = rotated_crops(image, torch.tensor([[10, 10]]), torch.tensor([0.0, math.pi / 2]), 8)
    assert crops.shape == (1, 2, 1, 8, 8)
    centre = 4
    assert torch.isclose(crops[0, 0, 0, centre, centre + 3], torch.tensor(1.0))
    assert torch.isclose(crops[0, 1, 0, centre + 3, centre], torch.tensor(1.0), atol=1e-5)
    assert float(crops[0, 1].sum()) == pytest.approx(1.0, abs=1e-4)


def test_cross_correlate_is_centred_on_the_kernel_centre():
    """out[y, x] = correlation of the zero-padded query with the kernel centred on (y, x)."""
    torch.manual_seed(0)
    query = torch.randn(2, 3, 4, 20, 15)
    kernels = torch.randn(2, 5, 4, 6, 6)
    out = cross_correlate(query, kernels)
    assert out.shape == (2, 3, 5, 20, 15)
    for b in range(2):
        padded = torch.nn.functional.pad(query[b], (3, 3, 3, 3))
        direct = torch.nn.functional.conv2d(padded, kernels[b])[..., :20, :15]
        assert torch.allclose(out[b], direct, atol=1e-3)


def test_cross_correlate_gradients_match_direct_convolution():
    """The hand-written backward equals autograd through conv2d, and the spectrum path (`act`)
    gives the same logits."""
    torch.manual_seed(0)
    query = torch.randn(2, 3, 4, 21, 14, dtype=torch.float64, requires_grad=True)
    kernels = torch.randn(2, 5, 4, 6, 6, dtype=torch.float64, requires_grad=True)
    weights = torch.randn(2, 3, 5, 21, 14, dtype=torch.float64)
    (cross_correlate(query, kernels) * weights).sum().backward()
    fft_grads = query.grad.clone(), kernels.grad.clone()
    query.grad = kernels.grad = None
    direct = torch.stack(
        [
            torch.nn.functional.conv2d(torch.nn.functional.pad(query[b], (3, 3, 3, 3)), kernels[b])[
                ..., :21, :14
            ]
            for b in range(2)
        ]
    )
    (direct * weights).sum().backward()
    assert torch.allclose(fft_grads[0], query.grad, atol=1e-9)
    assert torch.allclose(fft_grads[1], kernels.grad, atol=1e-9)
    with torch.no_grad():
        spectrum = kernel_spectrum(kernels, (21, 14))
        assert torch.allclose(correlate_spectrum(query, spectrum, 6), direct, atol=1e-9)


def test_cross_correlate_takes_bfloat16_features():
    """As CUDA's bf16 autocast (configs/gpu/bf16.yaml) hands them over: correlated in float32,
    gradients back in bfloat16."""
    torch.manual_seed(0)
    query = torch.randn(1, 2, 3, 20, 15).bfloat16().requires_grad_()
    kernels = torch.randn(1, 4, 3, 6, 6).bfloat16().requires_grad_()
    out = cross_correlate(query, kernels)
    assert out.dtype == torch.float32
    assert torch.equal(out, cross_correlate(query.float(), kernels.float()))
    out.sum().backward()
    assert query.grad.dtype == kernels.grad.dtype == torch.bfloat16


def test_transport_logits_shape_and_one_softmax_over_views():
    torch.manual_seed(0)
    transport = Transport(feature_channels=3, n_rotations=4, crop_size=8, width=4)
    pick = torch.randn(2, 6, 24, 16)
    places = torch.randn(2, 3, 6, 24, 16)
    pixels = torch.tensor([[5, 5], [10, 8]])
    logits = transport(pick, pixels, places)
    assert logits.shape == (2, 3, 4, 24, 16)
    bins = torch.tensor([1, 3])
    loss = placement_cross_entropy(logits, pixels, bins)
    flat = logits.flatten(1).log_softmax(1)
    expected = -(flat[0, (1 * 24 + 5) * 16 + 5] + flat[1, (3 * 24 + 10) * 16 + 8]) / 2
    assert torch.isclose(loss, expected, atol=1e-5)


def test_transport_pick_rotation_shifts_rotation_bins():
    """Turning the picked object by +90 deg (+2 of 8 bins) shifts the logits by -2 bins, exactly."""
    torch.manual_seed(0)
    n_rot, size = 8, 33
    transport = Transport(feature_channels=3, n_rotations=n_rot, crop_size=16, width=4)
    scene = torch.zeros(1, 6, size, size)
    scene[..., 10:23, 10:23] = torch.randn(1, 6, 13, 13)  # content near the pick pixel only
    # +90 deg about world z (x = columns towards y = rows) about the centre pixel (16, 16).
    turned = torch.rot90(scene, k=-1, dims=(-2, -1))
    probe = torch.zeros(1, 1, size, size)
    probe[..., 16, 19] = 1.0
    assert torch.rot90(probe, k=-1, dims=(-2, -1))[0, 0, 19, 16] == 1.0
    place = torch.randn(1, 1, 6, 24, 16)
    pick_pixel = torch.tensor([[16, 16]])
    with torch.no_grad():
        logits = transport(scene, pick_pixel, place)[0, 0]
        logits_turned = transport(turned, pick_pixel, place)[0, 0]
    shift = n_rot // 4
    assert torch.allclose(logits_turned, logits.roll(-shift, dims=0), atol=1e-3)
    assert not torch.allclose(logits_turned, logits, atol=1e-3)
    # A label consistent with the yaw convention: the best bin moves by -2.
    assert (
        int(logits_turned.amax((1, 2)).argmax())
        == (int(logits.amax((1, 2)).argmax()) - shift) % n_rot
    )


def test_pose_regression_shapes_and_gradients():
    torch.manual_seed(0)
    heads = PoseRegression(n_rotations=4, crop_size=8, width=4, n_features=4)
    image = torch.randn(2, 6, 24, 16, requires_grad=True)
    out = heads(
        image,
        torch.tensor([[3, 3], [20, 10]]),
        image,
        torch.tensor([[0, 0], [23, 15]]),
        torch.tensor([0, 3]),
    )
    assert out.shape == (2, 3)
    out.sum().backward()
    assert image.grad is not None and float(image.grad.abs().sum()) > 0


def test_rotation_columns_round_trip():
    quat = torch.tensor(g.euler_to_quat(0.3, -0.2, 2.0), dtype=torch.float64)
    matrix = quat_to_matrix(quat)
    assert torch.allclose(matrix, torch.tensor(g.quat_to_matrix(quat.numpy())), atol=1e-9)
    assert torch.allclose(rotation_from_columns(columns_from_rotation(matrix)), matrix, atol=1e-9)


def test_transport_translation():
    """Moving the picked object with its pick pixel leaves the place logits unchanged; moving the
    place content moves the correlation peak by the same offset."""
    torch.manual_seed(0)
    transport = Transport(feature_channels=3, n_rotations=4, crop_size=8, width=4)
    scene = torch.zeros(1, 6, 40, 24)
    scene[..., 8:13, 6:11] = torch.randn(1, 6, 5, 5)
    moved = scene.roll((16, 8), dims=(-2, -1))
    place = torch.randn(1, 1, 6, 24, 16)
    with torch.no_grad():
        logits = transport(scene, torch.tensor([[10, 8]]), place)
        logits_moved = transport(moved, torch.tensor([[26, 16]]), place)
    assert torch.allclose(logits, logits_moved, atol=1e-4)
    kernels = torch.randn(1, 4, 3, 8, 8)
    kernels = kernels / kernels.flatten(2).norm(dim=2)[..., None, None, None]  # unit norm
    query = torch.zeros(1, 1, 3, 40, 24)
    query[..., 10:18, 4:12] = kernels[0, 2]  # content that kernel 2 matches best
    peak = cross_correlate(query, kernels)[0, 0]
    shifted = cross_correlate(query.roll((12, 8), dims=(-2, -1)), kernels)[0, 0]
    assert unravel_argmax(peak)[0] == 2
    rotation, row, col = unravel_argmax(peak)
    assert unravel_argmax(shifted) == (rotation, row + 12, col + 8)
