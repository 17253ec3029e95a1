"""One colour for every 2D edit of a run: each call's edit brought to the calls' consensus.

A diffusion editor asked the same thing on two views answers in two shades (a cast a few
percent off, a lighter or darker tone): per-view colour inconsistency, which reconstructions
from edited views meet as exposure and white balance that differ between photographs. The loop
sees one edit per iteration, so whatever averaging it does carries the last few calls' casts.

Here a call's colour is read where it is least ambiguous: on the pixels the region covers
whole that the edit changed, the per-channel median of edit / unedited image. For a recolour
that ratio is the new colour over the old albedo at each pixel (the shading cancels), the same
from every view of the region; calls differ by their cast. The run keeps every call's ratio;
their per-channel median is the consensus, and a call's edit is moved to it by adding
(consensus - own) x unedited where the edit acted (the pixel's region share times how much the
edit changed it, up to `FULL_CHANGE`): a pure pixel recoloured as `own x unedited` becomes
`consensus x unedited`, an outline pixel moves by its share, an unedited one not at all.

A region with too few pure changed pixels in a view (`MIN_PIXELS`: a 3-px tooth) is not read
and not moved; the first call is its own consensus. A pattern (stripes) is not one colour over
the region: the pixels its edges cross mix it with the region's own, in a proportion that
changes from view to view as much as a call's cast does, so the loop leaves it as it is.
"""

from __future__ import annotations

import numpy as np

MIN_PIXELS = 8  # pure changed pixels a view must show for its call's colour to be read
FULL_CHANGE = 0.05  # a pixel changed this much (some channel) counts as edited in full
DARK = 0.02  # unedited pixels darker than this (every channel) say nothing about a ratio


def pure_pixels(share: np.ndarray, rays: int) -> np.ndarray:
    """(H, W) bool: the pixels a region covers whole, from its (H, W) `share` of each pixel's
    `rays` label rays; with one ray a pixel, those whose 3 x 3 neighbourhood is all region."""
    import cv2

    whole = np.asarray(share) >= 1.0
    if rays > 1:
        return whole
    return cv2.erode(whole.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)


def call_colour(edited: np.ndarray, unedited: np.ndarray, pure: np.ndarray) -> np.ndarray | None:
    """(3,) per-channel median of edited / unedited over the (H, W) bool `pure` pixels (the
    region covers them whole) that the (H, W, 3) edit changed by at least `FULL_CHANGE` and
    that are not dark; None when fewer than `MIN_PIXELS` are."""
    edited = np.asarray(edited, np.float32)
    unedited = np.asarray(unedited, np.float32)
    changed = np.abs(edited - unedited).max(-1) >= FULL_CHANGE
    use = np.asarray(pure, bool) & changed & (unedited.max(-1) > DARK)
    if int(use.sum()) < MIN_PIXELS:
        return None
    return np.median(edited[use] / np.maximum(unedited[use], DARK), axis=0).astype(np.float32)


def consensus(colours) -> np.ndarray:
    """(3,) per-channel median of the calls' (K, 3) colours (K >= 1)."""
    return np.median(np.asarray(colours, np.float32).reshape(-1, 3), axis=0)


def to_consensus(edited: np.ndarray, unedited: np.ndarray, share: np.ndarray, own: np.ndarray,
                 agreed: np.ndarray) -> np.ndarray:
    """(H, W, 3) the edit moved from its call's colour `own` (3,) to the consensus `agreed`
    (3,): plus (agreed - own) x unedited, weighted per pixel by the (H, W) region `share` in
    [0, 1] times how much the edit changed the pixel (its largest channel change over
    `FULL_CHANGE`, at most 1); clipped to [0, 1]."""
    edited = np.asarray(edited, np.float32)
    unedited = np.asarray(unedited, np.float32)
    acted = np.clip(np.abs(edited - unedited).max(-1) / FULL_CHANGE, 0.0, 1.0)
    weight = (np.asarray(share, np.float32) * acted)[..., None]
    shift = (np.asarray(agreed, np.float32) - np.asarray(own, np.float32)) * unedited
    return np.clip(edited + weight * shift, 0.0, 1.0)
