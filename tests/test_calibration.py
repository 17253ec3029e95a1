"""Each 2D edit brought to the run's consensus colour: a call's colour is the per-channel
median ratio of its edit to the unedited image on the region's pure changed pixels, and moving
it to the consensus recolours a pure pixel as consensus x unedited, an outline pixel by its
share, an unchanged pixel not at all."""

import numpy as np
import pytest

from gae_jax.edit import calibration


def textured(shape=(24, 32), seed=0):
    """(H, W, 3) an unedited image with texture and shading in (0.1, 0.9)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.1, 0.9, shape + (3,)).astype(np.float32)


def test_a_calls_colour_is_the_median_ratio_on_pure_changed_pixels():
    unedited = textured()
    pure = np.zeros(unedited.shape[:2], bool)
    pure[4:20, 6:26] = True
    gain = np.array([0.5, 1.2, 0.8], np.float32)
    edited = unedited.copy()
    edited[pure] = unedited[pure] * gain
    edited[0:4] = 0.0  # changed, but not the region's pure pixels: not read
    np.testing.assert_allclose(calibration.call_colour(edited, unedited, pure), gain, rtol=1e-5)

    # A partial edit: the pixels it left are not read (brute force median over the rest).
    partial = edited.copy()
    partial[4:12, 6:26] = unedited[4:12, 6:26]
    np.testing.assert_allclose(calibration.call_colour(partial, unedited, pure), gain,
                               rtol=1e-5)
    half = pure.copy()
    half[4:12] = False
    ratios = (partial / unedited)[half & (np.abs(partial - unedited).max(-1) >= 0.05)]
    np.testing.assert_allclose(calibration.call_colour(partial, unedited, pure),
                               np.median(ratios, 0), rtol=1e-5)

    few = np.zeros_like(pure)
    few[5, 6:6 + calibration.MIN_PIXELS - 1] = True
    assert calibration.call_colour(edited, unedited, few) is None
    assert calibration.call_colour(unedited, unedited, pure) is None  # nothing changed


def test_moving_to_the_consensus_recolours_by_share_and_leaves_the_unchanged():
    unedited = textured(seed=1)
    own, agreed = np.array([0.5, 1.2, 0.8]), np.array([0.6, 1.0, 0.9])
    share = np.zeros(unedited.shape[:2], np.float32)
    share[4:20, 6:26] = 1.0
    share[4:20, 26] = 0.25  # an outline column the region covers a quarter of
    edited = unedited * (1 + share[..., None] * (own - 1))
    edited[10:12, 8:10] = unedited[10:12, 8:10]  # a patch the call left unedited
    moved = calibration.to_consensus(edited, unedited, share, own, agreed)
    inner = share == 1.0
    inner[10:12, 8:10] = False
    np.testing.assert_allclose(moved[inner], (unedited * agreed)[inner], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(moved[10:12, 8:10], unedited[10:12, 8:10])
    np.testing.assert_allclose(moved[share == 0], edited[share == 0])
    # The quarter-covered column changed by at least FULL_CHANGE moves by a quarter of the
    # consensus shift; one that changed less moves in proportion to its change.
    column = moved[4:20, 26]
    change = np.abs(edited - unedited).max(-1)[4:20, 26]
    acted = np.clip(change / calibration.FULL_CHANGE, 0, 1)[:, None]
    expected = edited[4:20, 26] + 0.25 * acted * (agreed - own) * unedited[4:20, 26]
    np.testing.assert_allclose(column, np.clip(expected, 0, 1), rtol=1e-5, atol=1e-6)


def test_the_consensus_is_the_per_channel_median():
    calls = [np.array([0.5, 1.0, 2.0]), np.array([0.7, 0.2, 1.0]), np.array([0.6, 3.0, 0.1])]
    np.testing.assert_allclose(calibration.consensus(calls), [0.6, 1.0, 1.0])
    np.testing.assert_allclose(calibration.consensus(calls[:1]), calls[0])


@pytest.mark.parametrize("rays", [1, 4])
def test_pure_pixels_are_whole_coverage_or_the_labels_interior(rays):
    share = np.zeros((8, 8), np.float32)
    share[2:6, 2:6] = 1.0
    share[2:6, 6] = 0.5
    pure = calibration.pure_pixels(share, rays)
    expected = share >= 1.0
    if rays == 1:
        expected = np.zeros_like(expected)
        expected[3:5, 3:5] = True
    np.testing.assert_array_equal(pure, expected)
