import numpy as np

from nerf_transporter.data.preprocess import COLOUR_MEAN, COLOUR_STD, network_input


def test_network_input_layout():
    colour = np.zeros((2, 4, 5, 3), dtype=np.uint8)
    colour[..., 0] = 255
    height = np.full((2, 4, 5), 0.02, dtype=np.float32)
    x = network_input(colour, height)
    assert x.shape == (2, 6, 4, 5)
    assert np.isclose(float(x[0, 0, 0, 0]), (1.0 - COLOUR_MEAN) / COLOUR_STD, rtol=1e-5)
    assert float(x[0, 1, 0, 0]) < 0 and float(x[0, 3, 0, 0]) == float(x[0, 5, 0, 0])
