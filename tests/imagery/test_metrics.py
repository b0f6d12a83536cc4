import math

import numpy as np
import pytest

from nerf_transporter.imagery import height_mae_mm, psnr


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
