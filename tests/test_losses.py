"""Losses: SSIM against a plain per-pixel numpy loop, PSNR closed form, gradients in float64."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gae_jax.render import losses


def naive_ssim(a, b):
    """Per-pixel, per-channel SSIM with an explicit 11x11 window and zero padding."""
    g = losses.gaussian_window()
    win = np.outer(g, g)
    h, w, c = a.shape
    out = np.zeros_like(a)
    for ch in range(c):
        pa = np.pad(a[..., ch], 5)
        pb = np.pad(b[..., ch], 5)
        for i in range(h):
            for j in range(w):
                x, y = pa[i:i + 11, j:j + 11], pb[i:i + 11, j:j + 11]
                mx, my = (win * x).sum(), (win * y).sum()
                vx = (win * x * x).sum() - mx ** 2
                vy = (win * y * y).sum() - my ** 2
                cxy = (win * x * y).sum() - mx * my
                out[i, j, ch] = ((2 * mx * my + losses.SSIM_C1) * (2 * cxy + losses.SSIM_C2)) / (
                    (mx ** 2 + my ** 2 + losses.SSIM_C1) * (vx + vy + losses.SSIM_C2))
    return out


def test_ssim_matches_naive_loop_and_is_one_for_identical_images(x64):
    rng = np.random.default_rng(0)
    a = rng.uniform(size=(14, 17, 3))
    b = np.clip(a + rng.normal(scale=0.1, size=a.shape), 0, 1)
    np.testing.assert_allclose(losses.ssim_map(jnp.asarray(a), jnp.asarray(b)), naive_ssim(a, b),
                               atol=1e-12)
    np.testing.assert_allclose(losses.ssim(jnp.asarray(a), jnp.asarray(a)), 1.0, atol=1e-12)


def test_psnr_closed_form_and_mask(x64):
    a = jnp.zeros((8, 8, 3))
    b = jnp.full((8, 8, 3), 0.1)
    np.testing.assert_allclose(losses.psnr(a, b), 20.0, atol=1e-9)
    mask = jnp.zeros((8, 8), bool).at[:4].set(True)
    b2 = b.at[4:].set(0.5)
    np.testing.assert_allclose(losses.psnr(a, b2, mask), 20.0, atol=1e-9)


def test_loss_gradients_match_finite_differences(x64):
    rng = np.random.default_rng(1)
    a = jnp.asarray(rng.uniform(size=(12, 13, 3)))
    b = jnp.asarray(rng.uniform(size=(12, 13, 3)))
    check_grads(lambda x: losses.photometric(x, b), (a,), order=1, modes=["rev"], eps=1e-6)
    check_grads(lambda x: losses.ssim(x, b), (a,), order=1, modes=["rev"], eps=1e-6)


def test_regularisers_penalise_only_beyond_the_threshold(x64):
    means = jnp.asarray([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 3.0, 0.0]])
    np.testing.assert_allclose(losses.position_regulariser(means), (3.0 - 1.0) / 3, atol=1e-12)
    visible = jnp.asarray([True, True, False])
    np.testing.assert_allclose(losses.position_regulariser(means, visible), 0.0, atol=1e-12)
    log_scales = jnp.log(jnp.asarray([[0.1, 0.2, 0.3], [1.6, 0.6, 0.6]]))
    np.testing.assert_allclose(losses.scale_regulariser(log_scales), 0.5, atol=1e-12)
    g = jax.grad(lambda m: losses.position_regulariser(m))(means)
    assert np.all(np.isfinite(np.asarray(g))) and np.allclose(g[:2], 0)
    check_grads(lambda s: losses.scale_regulariser(s), (log_scales,), order=1, modes=["rev"],
                eps=1e-6)


def test_region_codes_tell_every_two_regions_apart_by_two_bits():
    for r in (1, 3, 10, 15):
        codes = losses.region_codes(r)
        assert codes.shape[0] == r + 1 and not codes[0].any()
        assert np.all(codes[1:].sum(1) == 2)
        distance = np.abs(codes[:, None] - codes[None, :]).sum(-1)
        assert distance[~np.eye(r + 1, dtype=bool)].min() >= 2


def test_region_loss_is_the_per_pixel_l1_to_the_labels_codes(x64):
    rng = np.random.default_rng(0)
    codes = losses.region_codes(3)
    weights = rng.uniform(0, 0.6, (5, 4, codes.shape[1]))
    labels = np.array([[0, 1, 2, -1]] * 4 + [[-2, -2, 0, 1]])
    value = float(losses.region_loss(jnp.asarray(weights), jnp.asarray(labels[..., None]),
                                     codes))
    expected = 0.0
    for y in range(5):
        for x in range(4):
            if labels[y, x] < -1:
                continue  # unknown: not counted
            expected += np.abs(weights[y, x] - codes[labels[y, x] + 1]).sum()
    assert value == pytest.approx(expected / 20)
    check_grads(lambda w: losses.region_loss(w, jnp.asarray(labels[..., None]), codes),
                (jnp.asarray(weights),), order=1, modes=("rev",))
    exact = codes[np.maximum(labels + 1, 0)]
    assert float(losses.region_loss(jnp.asarray(exact), jnp.asarray(labels[..., None]),
                                    codes)) == 0.0


def _region_loss_by_pixel(weights, samples, codes, pixel_weight=None) -> float:
    """The region loss as a loop over pixels: each pixel's L1 to the mean code of its rays,
    times its `pixel_weight` (H, W; default 1), summed over the pixels without an unknown ray
    (-2) and divided by all H x W pixels."""
    h, w = samples.shape[:2]
    pixel_weight = np.ones((h, w)) if pixel_weight is None else pixel_weight
    total = 0.0
    for y in range(h):
        for x in range(w):
            if (samples[y, x] < -1).any():
                continue
            target = np.mean([codes[s + 1] for s in samples[y, x]], axis=0)
            total += pixel_weight[y, x] * np.abs(weights[y, x] - target).sum()
    return total / (h * w)


def test_region_loss_asks_an_edge_pixel_for_the_mix_its_samples_say(x64):
    """With several label samples per pixel the target is the mean of their codes: a pixel
    half lips, half skin is matched exactly by an even mix of the two codes and not by either
    alone; a pixel with one unknown sample is not counted."""
    rng = np.random.default_rng(1)
    codes = losses.region_codes(4)
    samples = rng.integers(-1, 4, (6, 5, 4))
    samples[0, 0] = [0, 0, -2, 1]  # one unknown ray: the pixel is left out
    weights = rng.uniform(0, 0.8, (6, 5, codes.shape[1]))
    value = float(losses.region_loss(jnp.asarray(weights), jnp.asarray(samples), codes))
    assert value == pytest.approx(_region_loss_by_pixel(weights, samples, codes))
    check_grads(lambda w: losses.region_loss(w, jnp.asarray(samples), codes),
                (jnp.asarray(weights),), order=1, modes=("rev",))
    half = np.array([[[0, 0, 1, 1]]])
    mix = 0.5 * (codes[1] + codes[2])
    assert float(losses.region_loss(jnp.asarray(mix[None, None]), jnp.asarray(half),
                                    codes)) == 0.0
    for alone in (codes[1], codes[2]):
        assert float(losses.region_loss(jnp.asarray(alone[None, None]), jnp.asarray(half),
                                        codes)) > 0.5


def test_region_loss_weighs_the_pixels_near_an_outline_as_asked(x64):
    """`outline_pixels` against a loop over each pixel's 3 x 3 neighbourhood (clipped at the
    image's edge) of rays; the weighted loss against the same loop with those pixels counted
    `outline_weight` times, and its gradient against finite differences."""
    rng = np.random.default_rng(2)
    codes = losses.region_codes(4)
    samples = np.zeros((9, 8, 4), int)
    samples[0] = np.repeat(rng.integers(-1, 4, (8, 1)), 4, axis=-1)
    samples[2:7, 2:7] = 2  # a block of another region: its inside is no outline
    samples[5, 2, 1] = 0  # a pixel an outline crosses
    samples[8, 0] = [0, -2, 0, 0]  # one unknown ray: the pixel is left out
    weights = rng.uniform(0, 0.8, (9, 8, codes.shape[1]))
    outline = np.zeros((9, 8), bool)
    for y in range(9):
        for x in range(8):
            near = samples[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2]
            outline[y, x] = near.min() != near.max()
    got = np.asarray(losses.outline_pixels(jnp.asarray(samples, jnp.int8)))
    np.testing.assert_array_equal(got, outline)
    assert outline[5, 1:4].all() and not outline[3:6, 4:6].any() and not outline[8, 3:].any()
    expected = _region_loss_by_pixel(weights, samples, codes, np.where(outline, 5.0, 1.0))
    value = float(losses.region_loss(jnp.asarray(weights), jnp.asarray(samples), codes, 5.0))
    assert value == pytest.approx(expected)
    assert value > float(losses.region_loss(jnp.asarray(weights), jnp.asarray(samples), codes))
    check_grads(lambda w: losses.region_loss(w, jnp.asarray(samples), codes, 5.0),
                (jnp.asarray(weights),), order=1, modes=("rev",))
    from gae_jax.fit.config import ReconstructConfig

    for bad in (dict(region_outline_weight=0.0), dict(unseen_outline_weight=-1.0)):
        with pytest.raises(ValueError, match="outline_weight"):
            ReconstructConfig(**bad)


def test_change_coherence_pulls_each_member_to_the_colour_of_its_regions_mean_change(x64):
    """Value against a loop over the members: the squared distance of each member's colour from
    (c0 + f) exp(mean change of its group's members) - f; gradient: finite differences with
    those targets frozen (the prior pulls each member, not the means), zero off the members."""
    rng = np.random.default_rng(0)
    origin = rng.uniform(0, 1, (12, 3))
    colors = rng.uniform(0, 1, (12, 3))
    members = np.array([1, 1, 0, 1, 0, 1, 1, 1, 0, 1, 1, 0], bool)
    groups = np.array([0, 2, 2, 0, 1, 2, 0, 2, 1, 2, 0, 0])
    f = losses.CHANGE_FLOOR
    change = np.log(colors + f) - np.log(origin + f)
    target = np.zeros_like(colors)
    for i in range(12):
        same = members & (groups == groups[i])
        mean = change[same].mean(0) if same.any() else np.zeros(3)
        target[i] = (origin[i] + f) * np.exp(mean) - f
    expected = sum(((colors[i] - target[i]) ** 2).sum() for i in range(12) if members[i])
    args = (jnp.asarray(colors), jnp.asarray(origin), jnp.asarray(members), jnp.asarray(groups))
    assert float(losses.change_coherence(*args, 3)) == pytest.approx(expected, rel=1e-10)
    grad = np.asarray(jax.grad(losses.change_coherence)(*args, 3))

    def frozen(c):
        return (((c - target) ** 2) * members[:, None]).sum()

    eps = 1e-6
    numeric = np.zeros_like(colors)
    for idx in np.ndindex(colors.shape):
        step = np.zeros_like(colors)
        step[idx] = eps
        numeric[idx] = (frozen(colors + step) - frozen(colors - step)) / (2 * eps)
    np.testing.assert_allclose(grad, numeric, rtol=1e-6, atol=1e-9)
    assert not grad[~members].any()
    # members that share their group's change (in the floored ratio) are at rest
    ratios = np.exp(np.array([[-0.7, 0.2, -1.5], [0.3, 0.3, 0.3], [-2.0, 0.0, 0.5]]))
    shared = (origin + f) * ratios[groups] - f
    rest = losses.change_coherence(jnp.asarray(shared), *args[1:], 3)
    assert float(rest) == pytest.approx(0.0, abs=1e-20)
    assert float(losses.change_coherence(jnp.asarray(origin * 0.5), *args[1:], 3)) > 0
