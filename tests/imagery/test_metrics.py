import math

import numpy as np
import pytest

from nerf_transporter.imagery import height_mae_mm, psnr
from nerf_transporter.imagery.metrics import colour_edges, footprint_errors


def test_psnr_of_a_one_level_error_everywhere():
    target = np.full((4, 5, 3), 100, np.uint8)
    assert psnr(target, target) == math.inf
    assert psnr(target + 1, target) == pytest.approx(20 * math.log10(255.0))


def test_height_mae_overall_and_on_objects():
    target = np.array([[0.0, 0.0], [0.004, 0.05]])
    prediction = np.array([[0.001, -0.001], [0.004, 0.04]])
    overall, on_objects = height_mae_mm(prediction, target)
    assert overall == pytest.approx((1 + 1 + 0 + 10) / 4)
    assert on_objects == pytest.approx(10.0)  # only the 50 mm pixel is above 5 mm
    assert math.isnan(height_mae_mm(target[:1], target[:1])[1])


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="shape mismatch"):
        psnr(np.zeros((2, 2, 3), np.uint8), np.zeros((2, 3, 3), np.uint8))


def test_colour_edges_mark_an_outline_not_the_surfaces_either_side():
    image = np.full((20, 30, 3), 120, np.uint8)
    image[5:15, 10:20] = (200, 40, 40)  # a red square on a grey table
    thin = colour_edges(image, width=0)
    outline = np.zeros((20, 30), bool)
    outline[4:16, 9:21] = True
    outline[6:14, 11:19] = False  # a two-pixel ring across the square's border,
    outline[[4, 4, 15, 15], [9, 20, 9, 20]] = False  # but for its outer corners
    assert np.array_equal(thin, outline)
    grown = colour_edges(image, width=1)
    assert grown[3, 15] and grown[6, 15] and not grown[2, 15] and not grown[7, 15]
    assert not colour_edges(np.full((20, 30, 3), 120, np.uint8)).any()


def test_colour_edges_need_a_colour_image():
    with pytest.raises(ValueError, match=r"\[H, W, 3\] colour image"):
        colour_edges(np.zeros((20, 30), np.uint8))


def test_the_footprint_counts_the_object_pixels_added_and_missed():
    truth = np.zeros((40, 40), np.float32)
    truth[10:31, 10:31] = 0.03  # a 21 x 21 px block, 3 cm tall
    fatter = np.zeros_like(truth)
    fatter[9:32, 9:32] = 0.03  # one pixel all round: 23 x 23
    fatter[20, 20] = 0.004  # a hole, under the 5 mm that makes an object pixel
    errors = footprint_errors(fatter, truth)
    assert errors == {"extra_px": 23 * 23 - 21 * 21, "missing_px": 1, "iou": 440 / 529}
    assert np.isnan(footprint_errors(np.zeros_like(truth), np.zeros_like(truth))["iou"])
    with pytest.raises(ValueError, match="shape mismatch"):
        footprint_errors(truth[:10], truth)
