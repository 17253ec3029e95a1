"""FLAME: LBS against a naive per-joint numpy loop, gradients, and the real file formats."""

import os
import pickle
import sys
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from jax.test_util import check_grads

from gae_jax.model import flame, flame_io

# float64 JAX vs float64 numpy, same formulas: only summation order differs.
LBS_TOLERANCE = 1e-10


def random_model_arrays(seed=0, v=60, n_shape=6, n_expr=4, faces=40):
    """A FLAME-format model with random (non-zero) blendshapes, correctives and weights."""
    rng = np.random.default_rng(seed)
    weights = rng.uniform(size=(v, 5)) ** 3
    weights /= weights.sum(1, keepdims=True)
    j_reg = rng.uniform(size=(5, v)) * (rng.uniform(size=(5, v)) < 0.2)
    j_reg /= j_reg.sum(1, keepdims=True)
    return dict(
        v_template=rng.normal(scale=0.1, size=(v, 3)),
        shapedirs=rng.normal(scale=0.01, size=(v, 3, n_shape)),
        exprdirs=rng.normal(scale=0.01, size=(v, 3, n_expr)),
        posedirs=rng.normal(scale=0.01, size=(v, 3, 36)),
        J_regressor=j_reg, weights=weights,
        f=rng.integers(0, v, size=(faces, 3)))


def model_from(arrays, dtype=jnp.float64):
    return flame.FlameModel(
        v_template=jnp.asarray(arrays["v_template"], dtype),
        shapedirs=jnp.asarray(arrays["shapedirs"], dtype),
        exprdirs=jnp.asarray(arrays["exprdirs"], dtype),
        posedirs=jnp.asarray(arrays["posedirs"], dtype),
        j_regressor=jnp.asarray(arrays["J_regressor"], dtype),
        lbs_weights=jnp.asarray(arrays["weights"], dtype),
        faces=jnp.asarray(arrays["f"], jnp.int32))


def random_params(model, seed=1, scale=0.4):
    rng = np.random.default_rng(seed)
    r = lambda n: jnp.asarray(rng.normal(scale=scale, size=n))  # noqa: E731
    return flame.FlameParams(shape=r(model.num_shape), expr=r(model.num_expr), rotation=r(3),
                             neck=r(3), jaw=r(3), eyes=r(6), translation=r(3))


def naive_rodrigues(v):
    angle = np.linalg.norm(v + 1e-8)
    k = v / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def naive_lbs(a, p):
    """FLAME LBS written as a plain per-joint loop."""
    v_shaped = (a["v_template"] + a["shapedirs"] @ np.asarray(p.shape)
                + a["exprdirs"] @ np.asarray(p.expr))
    joints = a["J_regressor"] @ v_shaped
    pose = np.concatenate([p.rotation, p.neck, p.jaw, p.eyes]).reshape(5, 3)
    rots = [naive_rodrigues(pose[j]) for j in range(5)]
    feat = np.concatenate([(rots[j] - np.eye(3)).ravel() for j in range(1, 5)])
    v_posed = v_shaped + a["posedirs"] @ feat
    parents = [-1, 0, 1, 1, 1]
    world = []
    for j in range(5):
        local = np.eye(4)
        local[:3, :3] = rots[j]
        local[:3, 3] = joints[j] - (joints[parents[j]] if parents[j] >= 0 else 0)
        world.append(local if parents[j] < 0 else world[parents[j]] @ local)
    out = np.zeros_like(v_posed)
    for i in range(len(v_posed)):
        t = np.zeros((4, 4))
        for j in range(5):
            a_j = world[j].copy()
            a_j[:3, 3] -= world[j][:3, :3] @ joints[j]
            t += a["weights"][i, j] * a_j
        out[i] = (t @ np.append(v_posed[i], 1.0))[:3]
    return out + np.asarray(p.translation)


def test_lbs_matches_naive_numpy_loop(x64):
    arrays = random_model_arrays()
    model = model_from(arrays)
    params = random_params(model)
    np.testing.assert_allclose(jax.jit(flame.lbs)(model, params), naive_lbs(arrays, params),
                               atol=LBS_TOLERANCE)


def test_zero_pose_and_coefficients_give_the_template(x64):
    model = model_from(random_model_arrays())
    verts = flame.lbs(model, flame.zero_params(model, jnp.float64))
    np.testing.assert_allclose(verts, model.v_template, atol=1e-12)


def test_lbs_vmaps_over_frames(x64):
    model = model_from(random_model_arrays())
    frames = [random_params(model, seed=s) for s in range(3)]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *frames)
    batched = jax.vmap(flame.lbs, in_axes=(None, 0))(model, stacked)
    for i, p in enumerate(frames):
        np.testing.assert_allclose(batched[i], flame.lbs(model, p), atol=1e-12)


def test_lbs_gradients_match_finite_differences(x64):
    model = model_from(random_model_arrays(v=20, faces=10))
    params = random_params(model, scale=0.3)
    weights = jax.random.normal(jax.random.PRNGKey(0), (20, 3), jnp.float64)

    def loss(shape, expr, rotation, neck, jaw, eyes, translation):
        p = flame.FlameParams(shape, expr, rotation, neck, jaw, eyes, translation)
        return jnp.sum(flame.lbs(model, p) * weights)

    check_grads(loss, (params.shape, params.expr, params.rotation, params.neck, params.jaw,
                       params.eyes, params.translation), order=2, modes=["rev"], eps=1e-5)


def test_rodrigues_is_a_rotation_with_finite_gradient_at_zero(x64):
    r = flame.rodrigues(jnp.asarray([0.3, -1.2, 0.5]))
    # FLAME's angle |theta + 1e-8| leaves the axis 1e-8 off unit length, so R is orthonormal only
    # to ~1e-8 (as in smplx); the naive-loop test checks the exact formula.
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-8)
    g = jax.grad(lambda v: jnp.sum(flame.rodrigues(v) * jnp.arange(9.0).reshape(3, 3)))(
        jnp.zeros(3))
    assert np.all(np.isfinite(np.asarray(g)))


# --- files ---------------------------------------------------------------------------------------

class _FakeChumpyModule:
    """Registers a module `chumpy.ch` with a class `Ch` while a test writes a pickle."""

    def __enter__(self):
        pkg, mod = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")

        class Ch:
            def __init__(self, x):
                self.x = x

        Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
        mod.Ch = Ch
        pkg.ch = mod
        self.saved = {k: sys.modules.get(k) for k in ("chumpy", "chumpy.ch")}
        sys.modules.update({"chumpy": pkg, "chumpy.ch": mod})
        return Ch

    def __exit__(self, *exc):
        for k, v in self.saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


def write_flame_pickle(path, arrays, protocol=2):
    """A pickle laid out like FLAME's generic_model.pkl (shapedirs = identity | expression)."""
    shapedirs = np.concatenate([
        np.pad(arrays["shapedirs"], ((0, 0), (0, 0), (0, 300 - arrays["shapedirs"].shape[2]))),
        arrays["exprdirs"]], axis=2)
    with _FakeChumpyModule() as Ch:
        data = dict(
            v_template=Ch(arrays["v_template"]), shapedirs=Ch(shapedirs),
            posedirs=arrays["posedirs"], J_regressor=scipy.sparse.csc_matrix(arrays["J_regressor"]),
            weights=Ch(arrays["weights"]), f=arrays["f"].astype(np.uint32),
            kintree_table=np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]], np.int64),
            bs_style="lbs", bs_type="lrotmin", J=Ch(np.zeros((5, 3))))
        with open(path, "wb") as f:
            pickle.dump(data, f, protocol=protocol)


@pytest.mark.parametrize("protocol", [0, 2])
def test_loads_flame_pickle_with_sparse_and_chumpy_members(tmp_path, protocol, x64):
    arrays = random_model_arrays()
    path = tmp_path / "generic_model.pkl"
    write_flame_pickle(path, arrays, protocol)
    assert "chumpy" not in sys.modules
    model = flame_io.load_flame(str(path), n_shape=6, n_expr=4, dtype=jnp.float64)
    assert model.parents == flame.FLAME_PARENTS
    params = random_params(model)
    np.testing.assert_allclose(flame.lbs(model, params), naive_lbs(arrays, params),
                               atol=LBS_TOLERANCE)
    fewer = flame_io.load_flame(str(path), n_shape=3, n_expr=2)
    assert fewer.num_shape == 3 and fewer.num_expr == 2


def test_npz_round_trip(tmp_path, x64):
    model = model_from(random_model_arrays())
    path = str(tmp_path / "head.npz")
    flame_io.save_flame(model, path)
    loaded = flame_io.load_flame(path, n_shape=6, n_expr=4, dtype=jnp.float64)
    params = random_params(model)
    np.testing.assert_allclose(flame.lbs(loaded, params), flame.lbs(model, params), atol=1e-12)


class _Evil:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_malicious_pickle_is_refused_and_runs_nothing(tmp_path):
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pkl"
    with open(path, "wb") as f:
        pickle.dump({"v_template": _Evil(marker)}, f, protocol=2)
    with pytest.raises(flame_io.FlameFileError, match="refusing"):
        flame_io.load_flame(str(path))
    assert not marker.exists()


def test_missing_and_misshaped_fields_are_named(tmp_path):
    arrays = random_model_arrays()
    path = tmp_path / "m.npz"
    base = dict(v_template=arrays["v_template"], shapedirs=arrays["shapedirs"],
                exprdirs=arrays["exprdirs"], posedirs=arrays["posedirs"],
                J_regressor=arrays["J_regressor"], weights=arrays["weights"], f=arrays["f"],
                parents=np.array(flame.FLAME_PARENTS))
    missing = dict(base)
    del missing["weights"]
    np.savez(path, **missing)
    with pytest.raises(flame_io.FlameFileError, match="'weights'"):
        flame_io.load_flame(str(path), n_shape=6, n_expr=4)
    bad = dict(base, posedirs=arrays["posedirs"][..., :30])
    np.savez(path, **bad)
    with pytest.raises(flame_io.FlameFileError, match="'posedirs'"):
        flame_io.load_flame(str(path), n_shape=6, n_expr=4)
    nan = dict(base, v_template=np.full_like(arrays["v_template"], np.nan))
    np.savez(path, **nan)
    with pytest.raises(flame_io.FlameFileError, match="NaN"):
        flame_io.load_flame(str(path), n_shape=6, n_expr=4)
    with pytest.raises(flame_io.FlameFileError, match="components"):
        np.savez(path, **base)
        flame_io.load_flame(str(path), n_shape=50, n_expr=4)
    truncated = tmp_path / "t.pkl"
    write_flame_pickle(truncated, arrays)
    truncated.write_bytes(truncated.read_bytes()[:200])
    with pytest.raises(flame_io.FlameFileError, match="t.pkl"):
        flame_io.load_flame(str(truncated))


def test_teeth_follow_neck_and_jaw_rigidly(x64):
    from gae_jax.model import teeth as teeth_module

    arrays = random_model_arrays(v=60)
    model = model_from(arrays)
    upper, lower = np.arange(0, 15), np.arange(15, 30)
    teeth = teeth_module.with_teeth(model, upper, lower)
    assert teeth.num_vertices == 60 + 120 and teeth.faces.shape[0] == 40 + 168
    rest = np.asarray(teeth.v_template)[60:].reshape(8, 15, 3)  # rows in teeth.ROWS order
    d = np.mean(np.linalg.norm(arrays["v_template"][upper] - arrays["v_template"][lower], axis=1))
    upper_edge, lower_edge = rest[2], rest[3]
    np.testing.assert_allclose(upper_edge[:, 1] - lower_edge[:, 1], 0.2 * d, atol=1e-12)
    np.testing.assert_allclose(lower_edge[:, 2] - upper_edge[:, 2], -0.4 * d, atol=1e-12)
    zero = flame.zero_params(teeth, jnp.float64)
    jaw_open = flame.FlameParams(zero.shape, zero.expr, zero.rotation, zero.neck,
                                 jnp.asarray([0.4, 0.0, 0.0]), zero.eyes, zero.translation)
    posed = np.asarray(flame.lbs(teeth, jaw_open))[60:].reshape(8, 15, 3)
    upper_rows = list(teeth_module.UPPER_ROWS)
    lower_rows = [r for r in range(8) if r not in upper_rows]
    np.testing.assert_allclose(posed[upper_rows], rest[upper_rows], atol=1e-12)  # on the neck
    moved, still = posed[lower_rows].reshape(-1, 3), rest[lower_rows].reshape(-1, 3)
    assert np.abs(moved - still).max() > 1e-3
    dist = lambda x: np.linalg.norm(x[:, None] - x[None], axis=-1)  # noqa: E731
    np.testing.assert_allclose(dist(moved), dist(still), atol=1e-10)  # rigid
    np.testing.assert_allclose(flame.lbs(teeth, random_params(teeth))[:60],
                               flame.lbs(model, random_params(model)), atol=1e-12)


def test_flame_pickle_layout_round_trip(tmp_path, x64):
    arrays = random_model_arrays()
    model = model_from(arrays)
    path = str(tmp_path / "generic_model.pkl")
    flame_io.save_flame(model, path)
    with open(path, "rb") as f:
        raw = pickle.load(f)
    assert raw["shapedirs"].shape[-1] == flame_io.FLAME_IDENTITY_COMPONENTS + model.num_expr
    assert raw["kintree_table"].shape == (2, len(model.parents))
    loaded = flame_io.load_flame(path, n_shape=model.num_shape, n_expr=model.num_expr,
                                 dtype=jnp.float64)
    params = random_params(model)
    np.testing.assert_allclose(np.asarray(flame.lbs(loaded, params)),
                               np.asarray(flame.lbs(model, params)), rtol=1e-12, atol=1e-12)
    assert loaded.parents == model.parents


def test_face_regions_from_masks_take_the_smallest_mask_holding_the_face(tmp_path):
    faces = np.array([[0, 1, 2], [1, 2, 3], [3, 4, 5], [0, 4, 5]])
    masks = {"face": np.arange(6), "lips": np.array([1, 2, 3]), "left_eyeball": np.array([3, 4, 5]),
             "unknown_name": np.array([0])}
    path = tmp_path / "FLAME_masks.pkl"
    with open(path, "wb") as f:
        pickle.dump(masks, f, protocol=2)
    loaded = flame_io.load_flame_masks(str(path))
    regions = flame_io.face_regions_from_masks(faces, loaded, 6)
    from gae_jax.model.head import REGION_ID

    assert regions.tolist() == [REGION_ID["skin"], REGION_ID["lips"], REGION_ID["sclera"],
                                REGION_ID["skin"]]
    with pytest.raises(flame_io.FlameFileError, match="outside"):
        flame_io.face_regions_from_masks(faces, {"lips": np.array([9])}, 6)
