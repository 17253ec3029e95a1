"""The GAN scenario's sharpness metric (benchmarks/gan_scenario.py) against closed forms."""

import numpy as np

from benchmarks.gan_scenario import eroded, laplacian_energy


def test_laplacian_energy_of_polynomial_images_is_their_closed_form():
    y, x = np.mgrid[0:12, 0:10].astype(np.float64)
    mask = np.ones((12, 10), bool)
    linear = np.stack([0.3 * x + 0.1 * y] * 3, -1)
    assert laplacian_energy(linear, mask) < 1e-20  # a plane has no curvature
    # x^2 + y^2 in two channels: the 4-neighbour Laplacian is exactly 4 there, energy 2 * 16
    quadratic = np.stack([x ** 2 + y ** 2, x ** 2 + y ** 2, np.zeros_like(x)], -1)
    np.testing.assert_allclose(laplacian_energy(quadratic, mask), 2 * 16.0)


def test_laplacian_energy_counts_only_masked_interior_pixels():
    image = np.zeros((8, 8, 3))
    image[2, 2] = 1.0  # one spike: Laplacian -4 at it, +1 at its 4 neighbours (per channel)
    mask = np.zeros((8, 8), bool)
    mask[2, 2] = True
    np.testing.assert_allclose(laplacian_energy(image, mask), 3 * 16.0)
    mask[:] = False
    mask[6, 6] = True
    assert laplacian_energy(image, mask) == 0.0
    assert np.isnan(laplacian_energy(image, np.zeros((8, 8), bool)))


def test_eroded_shrinks_a_square_by_the_given_pixels_on_each_side():
    mask = np.zeros((2, 20, 20), bool)
    mask[:, 5:15, 5:15] = True
    out = eroded(mask, 2)
    assert out.shape == mask.shape and out.dtype == bool
    expected = np.zeros((20, 20), bool)
    expected[7:13, 7:13] = True
    np.testing.assert_array_equal(out[0], expected)
    np.testing.assert_array_equal(out[1], expected)
