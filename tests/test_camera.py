"""Camera conventions: OpenCV axes, look-at, projection of known points."""

import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.render.camera import focal_from_fov, look_at_w2c, make_camera


def test_look_at_puts_target_on_the_optical_axis_with_up_upwards(x64):
    eye, target = np.array([1.0, 2.0, -3.0]), np.array([0.2, -0.1, 0.5])
    w2c = look_at_w2c(eye, target, up=(0, 1, 0))
    rot = w2c[:3, :3]
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    p = rot @ target + w2c[:3, 3]
    np.testing.assert_allclose(p[:2], 0, atol=1e-12)
    assert p[2] > 0
    above = rot @ (target + np.array([0, 0.1, 0])) + w2c[:3, 3]
    assert above[1] < 0, "a point above the target must appear above the centre (y down)"


def test_camera_position_and_projection(x64):
    w2c = look_at_w2c([0.0, 0.0, -2.0], [0, 0, 0], up=(0, -1, 0))
    cam = make_camera(w2c, 64, 48, fov_degrees=90.0, dtype=jnp.float64)
    np.testing.assert_allclose(cam.position, [0, 0, -2.0], atol=1e-12)
    f = focal_from_fov(90.0, 64)
    assert f == pytest.approx(32.0)
    p = cam.world_to_camera(jnp.asarray([[0.5, 0.25, 0.0]]))[0]
    u = f * p[0] / p[2] + 32.0
    v = f * p[1] / p[2] + 24.0
    assert float(u) == pytest.approx(32.0 + 32.0 * 0.25)
    assert float(v) == pytest.approx(24.0 + 32.0 * 0.125)


def test_bad_camera_inputs_raise():
    with pytest.raises(ValueError, match="w2c"):
        make_camera(np.eye(3), 10, 10)
    with pytest.raises(ValueError, match="image size"):
        make_camera(np.eye(4), 0, 10)
    with pytest.raises(ValueError, match="coincide"):
        look_at_w2c([0, 0, 0], [0, 0, 0])
