"""A plain CPU transcription of the standard tile splatting algorithm (3DGS / gsplat), in torch,
for timing our renderer against in the same run (`benchmarks/render.py`). Needs torch (the `ip2p`
extra); nothing else in the package imports this module.

The steps gsplat runs, written directly: EWA projection (perspective Jacobian clamped to 1.3x
the field of view, 0.1 px^2 dilation as ours), a screen bounding box per Gaussian (the opacity-aware one
our renderer uses, so both draw exactly the same image), 16x16 tiles, each tile's Gaussians
sorted by (depth, index), and per tile a dense front-to-back composite over its pixels:
alpha = min(0.99, o exp(-q/2)), contributions under 1/255 skipped, a pixel stops before its
transmittance would fall under 1e-4. The backward pass is torch autograd of the same code.
Checked against the brute-force per-pixel compositor by `tests/test_tile_reference.py`.
"""

from __future__ import annotations

import math

import torch

TILE = 16
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
NEAR = 0.01
COV_DILATION = 0.1


def project(means, quats, scales, opacities, intrinsics, w2c, width, height):
    """(means2d (N, 2), conics (N, 3), depths (N,), half-extents (N, 2), visible (N,))."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    p = means @ rot.T + trans
    z = p[:, 2]
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, zq = q.unbind(-1)
    r = torch.stack([
        1 - 2 * (y * y + zq * zq), 2 * (x * y - w * zq), 2 * (x * zq + w * y),
        2 * (x * y + w * zq), 1 - 2 * (x * x + zq * zq), 2 * (y * zq - w * x),
        2 * (x * zq - w * y), 2 * (y * zq + w * x), 1 - 2 * (x * x + y * y)], -1).view(-1, 3, 3)
    m = r * scales[:, None, :]
    sigma = m @ m.transpose(1, 2)
    safe_z = torch.where(z > NEAR, z, torch.ones_like(z))
    lim_x = (width - cx) / fx + 0.15 * width / fx, cx / fx + 0.15 * width / fx
    lim_y = (height - cy) / fy + 0.15 * height / fy, cy / fy + 0.15 * height / fy
    tx = safe_z * torch.clamp(p[:, 0] / safe_z, -lim_x[1], lim_x[0])
    ty = safe_z * torch.clamp(p[:, 1] / safe_z, -lim_y[1], lim_y[0])
    zeros = torch.zeros_like(z)
    jac = torch.stack([fx / safe_z, zeros, -fx * tx / safe_z ** 2,
                       zeros, fy / safe_z, -fy * ty / safe_z ** 2], -1).view(-1, 2, 3)
    t = jac @ rot
    cov = t @ sigma @ t.transpose(1, 2) + COV_DILATION * torch.eye(2, dtype=means.dtype)
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = a * c - b * b
    conics = torch.stack([c / det, -b / det, a / det], -1)
    means2d = torch.stack([fx * p[:, 0] / safe_z + cx, fy * p[:, 1] / safe_z + cy], -1)
    reach = opacities >= ALPHA_MIN
    q_max = 2.0 * torch.log(255.0 * torch.where(reach, opacities, torch.ones_like(opacities)))
    extents = torch.sqrt(torch.clamp(q_max, min=0.0)[:, None] * torch.stack([a, c], -1))
    visible = (z > NEAR) & (det > 0) & reach
    return means2d, conics, z, extents, visible



def tile_lists(means2d, extents, depths, visible, width, height):
    """Per tile (row-major), the indices of the Gaussians whose box touches it, by depth."""
    with torch.no_grad():
        lo = torch.floor((means2d - extents) / TILE)
        hi = torch.floor((means2d + extents) / TILE)
        order = torch.argsort(depths, stable=True)
        lists = []
        for ty in range(math.ceil(height / TILE)):
            for tx in range(math.ceil(width / TILE)):
                hit = (visible[order] & (lo[order, 0] <= tx) & (hi[order, 0] >= tx)
                       & (lo[order, 1] <= ty) & (hi[order, 1] >= ty))
                lists.append(order[hit])
    return lists


def render(means, quats, scales, opacities, colors, intrinsics, w2c, width, height,
           background):
    """(H, W, C) image of the Gaussians (torch tensors; differentiable by autograd)."""
    means2d, conics, depths, extents, visible = project(means, quats, scales, opacities,
                                                        intrinsics, w2c, width, height)
    lists = tile_lists(means2d, extents, depths, visible, width, height)
    tiles_x = math.ceil(width / TILE)
    ys, xs = torch.meshgrid(torch.arange(TILE, dtype=means.dtype),
                            torch.arange(TILE, dtype=means.dtype), indexing="ij")
    rows = []
    for ty in range(math.ceil(height / TILE)):
        row = []
        for tx in range(tiles_x):
            idx = lists[ty * tiles_x + tx]
            px = (xs + tx * TILE + 0.5).reshape(-1, 1)
            py = (ys + ty * TILE + 0.5).reshape(-1, 1)
            if len(idx) == 0:
                row.append(background.expand(TILE * TILE, -1))
                continue
            dx, dy = px - means2d[idx, 0], py - means2d[idx, 1]
            a, b, c = conics[idx].unbind(-1)
            q = a * dx * dx + 2 * b * dx * dy + c * dy * dy
            alpha = torch.clamp(opacities[idx] * torch.exp(-0.5 * q), max=ALPHA_MAX)
            alpha = torch.where((alpha >= ALPHA_MIN) & (q >= 0), alpha, torch.zeros_like(alpha))
            through = torch.cumprod(1.0 - alpha, dim=1)
            used = torch.cumsum((through < T_MIN).to(alpha.dtype), dim=1) == 0
            before = torch.cat([torch.ones_like(through[:, :1]), through[:, :-1]], 1)
            weight = alpha * before * used
            final = torch.where(used, through, torch.full_like(through, 2.0)).min(1).values
            final = torch.where(used.any(1), torch.minimum(final, torch.ones_like(final)),
                                torch.ones_like(final))
            row.append(weight @ colors[idx] + final[:, None] * background)
        rows.append(torch.stack(row))
    grid = torch.stack(rows)  # (tiles_y, tiles_x, TILE * TILE, C)
    image = grid.view(len(rows), tiles_x, TILE, TILE, -1).permute(0, 2, 1, 3, 4)
    return image.reshape(len(rows) * TILE, tiles_x * TILE, -1)[:height, :width]
