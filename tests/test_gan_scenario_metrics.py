"""The GAN scenario's sharpness metric (gae_jax/run/gan_scenario.py) against closed forms."""

import numpy as np

from gae_jax.run.gan_scenario import eroded, laplacian_energy


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


def test_summary_pairs_each_weight_with_the_gan_off_at_the_same_seed_and_iterations():
    from gae_jax.run import gan_scenario
    from gae_jax.evaluation import protocols

    def record(best):
        modes = {p: dict(psnr_best=best, psnr_mean_of_modes=best + 3, lpips_best=best / 100,
                         sharpness=0.5) for p in protocols.PROTOCOLS}
        flicker = {p: {"flicker": {"ours": {"edited": 0.04}}} for p in protocols.PROTOCOLS}
        return dict(modes=modes, evaluation=flicker)

    weights, seeds = (0, 0.01), (0, 1, 2)
    off, on = (16.0, 18.0, 15.0), (16.5, 18.1, 15.3)
    results = {}
    for name in gan_scenario.rows(weights, seeds):
        results[name] = record(20.0)  # rows the summary does not pair here
    for s, (a, b) in enumerate(zip(off, on)):
        results[f"modes2/w0/seed{s}"] = record(a)
        results[f"modes2/w0.01/seed{s}"] = record(b)
    lines = gan_scenario.summary_lines(results, weights, seeds)
    row = {cells[0]: cells for cells in ([c.strip() for c in line.strip("|").split("|")]
                                         for line in lines if line.startswith("| w "))}
    assert row["w 0"][1] == "16.33 (15.00-18.00)" and row["w 0"][2] == "-"
    assert row["w 0.01"][2] == "+0.30 (+0.50 / +0.10 / +0.30)"
    assert row["w 0.01"][3] == "0.1"  # 0.30 over the GAN-off row's 3 dB seed range
    assert row["w 0.01"][4] == "0.166" and row["w 0.01"][5] == "+0.003 (+0.005 / +0.001 / +0.003)"
    assert row["w 0.01"][6] == "0.1"
    assert row["w 0.01"][7] == "19.63" and row["w 0.01"][9] == "0.0400"
    # the long rows pair with the long GAN-off rows: all 20 dB here, so no change
    long_row = row[f"w 0.01, {gan_scenario.LONG_ITERATIONS} it."]
    assert long_row[2].startswith("+0.00")
