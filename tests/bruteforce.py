"""A plain numpy (float64) splatting reference, independent of gae_jax's renderer.

Per pixel it composites *all* Gaussians in (depth, index) order with the 3DGS cut-offs; no tiles,
no capacities. Projection is re-derived here from the formulas (EWA with the perspective Jacobian,
frustum-clamped as in gsplat, a 0.1 px^2 dilation unless told), not imported.
"""

from __future__ import annotations

import numpy as np

ALPHA_MIN = 1.0 / 255.0
DILATION = 0.1
T_MIN = 1e-4


def rotation_from_quaternion(q):
    """(4,) wxyz, any norm -> (3, 3)."""
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
    ])


def project(means, quats, scales, intrinsics, w2c, width, height, near=0.01, dilation=DILATION):
    """Returns means2d (N,2), conics (N,3) [a,b,c] of the inverse 2D covariance, depth (N,), ok (N,)."""
    fx, fy, cx, cy = intrinsics
    n = len(means)
    means2d = np.zeros((n, 2))
    conics = np.zeros((n, 3))
    depth = np.zeros(n)
    ok = np.zeros(n, bool)
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    for i in range(n):
        p = rot @ means[i] + trans
        depth[i] = p[2]
        if p[2] < near:
            continue
        r = rotation_from_quaternion(quats[i])
        sigma = r @ np.diag(scales[i] ** 2) @ r.T
        lim_xp = (width - cx) / fx + 0.3 * 0.5 * width / fx
        lim_xn = cx / fx + 0.3 * 0.5 * width / fx
        lim_yp = (height - cy) / fy + 0.3 * 0.5 * height / fy
        lim_yn = cy / fy + 0.3 * 0.5 * height / fy
        tx = p[2] * min(max(p[0] / p[2], -lim_xn), lim_xp)
        ty = p[2] * min(max(p[1] / p[2], -lim_yn), lim_yp)
        jac = np.array([[fx / p[2], 0, -fx * tx / p[2] ** 2],
                        [0, fy / p[2], -fy * ty / p[2] ** 2]])
        cov = jac @ rot @ sigma @ rot.T @ jac.T + dilation * np.eye(2)
        det = np.linalg.det(cov)
        if det <= 0:
            continue
        inv = np.linalg.inv(cov)
        conics[i] = [inv[0, 0], inv[0, 1], inv[1, 1]]
        means2d[i] = [fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy]
        ok[i] = True
    return means2d, conics, depth, ok


def composite(means2d, conics, depth, ok, opacities, colors, width, height, background,
              mode="standard", beta=0.0, alpha_clamp=0.99, keep=None):
    """Composites every pixel over all Gaussians sorted by (depth, index).

    keep: optional (H, W, N) bool; False entries are left out of that pixel (used to emulate a
    per-tile capacity).
    Returns image (H, W, C), alpha (H, W), expected depth (H, W).
    """
    order = sorted(np.flatnonzero(ok), key=lambda i: (depth[i], i))
    ys, xs = np.mgrid[0:height, 0:width]
    px, py = xs + 0.5, ys + 0.5
    t = np.ones((height, width))
    done = np.zeros((height, width), bool)
    color = np.zeros((height, width, colors.shape[1]))
    dsum = np.zeros((height, width))
    for i in order:
        dx, dy = px - means2d[i, 0], py - means2d[i, 1]
        a, b, c = conics[i]
        q = a * dx * dx + 2 * b * dx * dy + c * dy * dy
        alpha = np.minimum(alpha_clamp, opacities[i] * np.exp(-0.5 * q))
        live = (alpha >= ALPHA_MIN) & (q >= 0) & ~done
        if keep is not None:
            live &= keep[:, :, i]
        t_next = t * (1 - alpha)
        stop = live & (t_next < T_MIN)
        use = live & ~stop
        done |= stop
        w = np.exp(-beta * (1 - t)) if mode == "wabe" else 1.0
        color += (use * alpha * t * w)[..., None] * colors[i]
        dsum += use * alpha * t * depth[i]
        t = np.where(use, t_next, t)
    image = color + t[..., None] * background
    alpha_out = 1 - t
    return image, alpha_out, dsum / np.maximum(alpha_out, 1e-8)


def render(gaussians, camera, background=None, mode="standard", beta=0.0, alpha_clamp=0.99):
    """Brute-force render of a gae_jax `Gaussians` with plain (N, C) colours."""
    g = {k: np.asarray(getattr(gaussians, k), np.float64)
         for k in ("means", "quats", "scales", "opacities", "colors")}
    intr = np.asarray(camera.intrinsics, np.float64)
    w2c = np.asarray(camera.w2c, np.float64)
    m2, con, dep, ok = project(g["means"], g["quats"], g["scales"], intr, w2c, camera.width,
                               camera.height)
    bg = np.zeros(g["colors"].shape[1]) if background is None else np.asarray(background)
    return composite(m2, con, dep, ok, g["opacities"], g["colors"], camera.width, camera.height,
                     bg, mode=mode, beta=beta, alpha_clamp=alpha_clamp)
