"""Editors: instruction parsing, the semantic edit against its closed form and against the ray-cast
ideal edit, the noise model, the OpenCV stylisers, and InstructPix2Pix on a tiny local pipeline."""

import json

import jax
import numpy as np
import pytest

from gae_jax import instructions
from gae_jax.scene import synthetic
from gae_jax.model import head
from gae_jax.edit.editors import make_editor, semantic, style
from gae_jax.scene.raycast import raycast

LIPS = head.REGION_ID["lips"]


def toy_render():
    """A 12 x 16 render: lips (shaded lips albedo) in the middle, skin around, -1 at the top."""
    regions = np.full((12, 16), head.REGION_ID["skin"])
    regions[4:8, 5:11] = LIPS
    regions[:2] = -1
    shade = np.linspace(0.5, 1.0, 16)[None, :].repeat(12, 0)
    albedo = np.where((regions == LIPS)[..., None], head.ALBEDO["lips"], head.ALBEDO["skin"])
    image = albedo * shade[..., None]
    image[:2] = 1.0
    return image.astype(np.float32), regions, shade


def test_semantic_edit_equals_the_closed_form_and_touches_only_the_region():
    image, regions, shade = toy_render()
    out = make_editor("semantic").edit(image, image, "turn the lips blue", jax.random.PRNGKey(0),
                                       dict(regions=regions))
    lips = regions == LIPS
    luma = np.array(head.ALBEDO["lips"]) @ semantic.LUMA
    expected = np.asarray(instructions.COLOURS["blue"]) * (
        (np.array(head.ALBEDO["lips"]) * shade[..., None]) @ semantic.LUMA / luma)[..., None]
    np.testing.assert_allclose(out[lips], expected[lips], atol=1e-5)
    np.testing.assert_array_equal(out[~lips], image[~lips])


def test_keeps_original_returns_the_original_outside_the_region():
    image, regions, _ = toy_render()
    original = np.clip(image * 0.5 + 0.3, 0, 1)  # e.g. the render has drifted from the original
    lips = regions == LIPS
    ctx = dict(regions=regions)
    key = jax.random.PRNGKey(0)
    kept = make_editor("semantic", keeps="original").edit(image, original, "turn the lips blue",
                                                          key, ctx)
    echoed = make_editor("semantic").edit(image, original, "turn the lips blue", key, ctx)
    np.testing.assert_array_equal(kept[~lips], original[~lips])
    np.testing.assert_array_equal(echoed[~lips], image[~lips])
    np.testing.assert_array_equal(kept[lips], echoed[lips])
    with pytest.raises(ValueError, match="keeps must be one of"):
        make_editor("semantic", keeps="both")


def test_bleed_spills_over_the_outline_and_into_what_the_region_hides():
    image, regions, _ = toy_render()
    teeth = head.REGION_ID["teeth"]
    regions[8, 6:10] = teeth  # just under the lips
    regions[11, 0] = teeth  # far from them
    key, ctx = jax.random.PRNGKey(0), dict(regions=regions)
    plain = make_editor("semantic", keeps="original").edit(image, image, "turn the lips blue",
                                                           key, ctx)
    out = make_editor("semantic", keeps="original", bleed=8).edit(
        image, image, "turn the lips blue", key, ctx)
    lips = regions == LIPS
    # bleed scales with the region's size: the 4 x 6 px lips' widest inscribed disk is 4 px
    bleed = 8 * semantic.thickness(lips) / semantic.FULL_SIZE_THICKNESS
    assert semantic.thickness(lips) == pytest.approx(4.0)
    np.testing.assert_array_equal(out[lips], plain[lips])
    # Brute force: Euclidean distance of every pixel to the nearest lips pixel.
    ly, lx = np.nonzero(lips)
    blue = np.asarray(instructions.COLOURS["blue"], np.float32)
    for y in range(12):
        for x in range(16):
            if lips[y, x]:
                continue
            d = np.sqrt(np.min((ly - y) ** 2 + (lx - x) ** 2))
            w = 1.0 if regions[y, x] == teeth and d <= 3 * bleed else max(0.0, 1 - d / (bleed + 1))
            own = (max(float(np.asarray(head.ALBEDO[head.REGIONS[regions[y, x]]]) @ semantic.LUMA),
                        1e-3) if regions[y, x] >= 0 else 1.0)
            spill = blue * min(max(float(image[y, x] @ semantic.LUMA) / own, 0.0), 1.5)
            np.testing.assert_allclose(out[y, x], (1 - w) * image[y, x] + w * spill, atol=1e-5)
    assert np.all(out[8, 6:10] != image[8, 6:10]), "the teeth under the lips are recoloured"
    np.testing.assert_array_equal(out[11, 0], image[11, 0])
    with pytest.raises(ValueError, match="bleed must be"):
        make_editor("semantic", bleed=-1)


def test_noise_is_driven_by_the_key_and_zero_noise_ignores_it():
    image, regions, _ = toy_render()
    ctx = dict(regions=regions)
    clean = make_editor("semantic")
    a = clean.edit(image, image, "turn the lips blue", jax.random.PRNGKey(0), ctx)
    b = clean.edit(image, image, "turn the lips blue", jax.random.PRNGKey(1), ctx)
    np.testing.assert_array_equal(a, b)
    noisy = make_editor("semantic", noise=1.0)
    edits = [noisy.edit(image, image, "turn the lips blue", jax.random.PRNGKey(k), ctx)
             for k in range(6)]
    np.testing.assert_array_equal(
        edits[0], noisy.edit(image, image, "turn the lips blue", jax.random.PRNGKey(0), ctx))
    assert all(np.abs(e - edits[0]).max() > 1e-3 for e in edits[1:])
    assert all(np.abs(e - a).max() > 1e-3 for e in edits)
    with pytest.raises(ValueError, match="noise"):
        make_editor("semantic", noise=1.5)
    with pytest.raises(ValueError, match="context\\['regions'\\]"):
        clean.edit(image, image, "turn the lips blue", jax.random.PRNGKey(0), {})


def test_semantic_edit_of_the_truth_matches_the_ray_cast_ideal_edit():
    model, assets = head.make_head()
    scene_shape = np.zeros(model.num_shape)
    intrinsics, w2c = synthetic.camera_rig(9, 64)
    camera = synthetic.Camera(intrinsics=intrinsics[synthetic.HELD_OUT_CAMERA],
                         w2c=w2c[synthetic.HELD_OUT_CAMERA], width=64, height=64)
    verts = np.asarray(model.v_template)
    faces = np.asarray(model.faces)
    shaded = synthetic.shaded_colors(model, assets.vertex_colors, scene_shape)
    truth = raycast(verts, faces, shaded, assets.face_regions, camera)
    instruction = instructions.parse("turn the lips blue")
    albedo = instructions.ideal_albedo(instruction, assets.vertex_colors, faces, assets.face_regions,
                                   verts)
    ideal = raycast(verts, faces, synthetic.shaded_colors(model, albedo, scene_shape),
                    assets.face_regions, camera)
    edit = make_editor("semantic").edit(truth.image, truth.image, "turn the lips blue",
                                        jax.random.PRNGKey(0), dict(regions=truth.regions))
    lips = truth.regions == LIPS
    assert lips.sum() > 20
    # Inside the lips the 2D recolour with recovered shading equals the 3D albedo edit.
    err = np.abs(edit[lips] - ideal.image[lips])
    assert np.median(err) < 0.02 and err.mean() < 0.04, (np.median(err), err.mean())
    np.testing.assert_array_equal(edit[~lips], truth.image[~lips])
    changed = np.abs(ideal.image - truth.image).max(-1) > 1e-6
    assert changed[lips].all() and not changed[truth.regions == head.REGION_ID["teeth"]].any()


# Inside a region, the recolour with fitted shading against the ray-cast ideal: mean absolute
# error per channel (the nine-term light misses a clamped Lambertian by ~3 %, and the coarse
# teeth's Gouraud shading by up to ~5 %, where a pixel's own ratio is not kept).
FITTED_SHADING_ERROR = 0.02


def _makehuman_view(size, distance, jaw_open, supersample=1):
    """The MakeHuman head from the near-frontal camera: its ray-cast image, region labels
    (and each ray's, `samples`), interpolated head-space normals, and a function giving the
    ideal edit of a prompt, `supersample` x `supersample` rays per pixel."""
    import dataclasses

    import jax.numpy as jnp

    from gae_jax.model import avatar as av
    from gae_jax.model import flame

    model, assets = head.make_head("makehuman")
    shape = np.zeros(model.num_shape)
    intrinsics, w2c = synthetic.camera_rig(9, size, distance=distance)
    camera = synthetic.Camera(intrinsics=intrinsics[synthetic.HELD_OUT_CAMERA],
                              w2c=w2c[synthetic.HELD_OUT_CAMERA], width=size, height=size)
    expr = np.zeros(model.num_expr)
    expr[assets.expr_names.index("jawOpen")] = jaw_open
    verts = np.asarray(flame.lbs(model, dataclasses.replace(
        flame.zero_params(model), expr=jnp.asarray(expr, jnp.float32))))
    faces = np.asarray(model.faces)
    truth = raycast(verts, faces, synthetic.shaded_colors(model, assets.vertex_colors, shape),
                    assets.face_regions, camera, supersample=supersample)
    normals = raycast(verts, faces, av.vertex_normals(np.asarray(model.v_template), faces),
                      assets.face_regions, camera).image
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-9)

    def ideal(prompt):
        albedo = instructions.ideal_albedo(instructions.parse(prompt), assets.vertex_colors,
                                           faces, assets.face_regions, verts)
        return raycast(verts, faces, synthetic.shaded_colors(model, albedo, shape),
                       assets.face_regions, camera, supersample=supersample).image

    return truth, normals, ideal


@pytest.mark.parametrize("size, distance, jaw_open, prompts", [
    (128, 0.68, 0.0, ["make the skin light blue", "make the hair blonde", "make the hair black",
                      "make the eyebrows white"]),
    (192, 0.45, 0.8, ["make the eyebrows black", "make the eyes light green",
                      "make the whites of the eyes dark red", "make the teeth yellow",
                      "make the teeth black", "make the tongue light blue",
                      "turn the lips navy blue"])])
def test_fitted_shading_recolours_every_region_as_the_ray_cast_ideal(size, distance, jaw_open,
                                                                     prompts):
    """With normals, textured regions (the MakeHuman hair and brows are painted strokes of
    skin and hair colour) get the named colour evenly shaded, as the ideal albedo edit does,
    where luminance over the region's albedo turns the strokes into blotches; uniform regions
    stay exact."""
    import cv2

    truth, normals, ideal = _makehuman_view(size, distance, jaw_open)
    for prompt in prompts:
        region = truth.regions == head.REGION_ID[instructions.parse(prompt).region]
        inner = cv2.erode(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert inner.sum() >= 20, prompt
        target = ideal(prompt)
        fitted = make_editor("semantic").edit(truth.image, truth.image, prompt,
                                              jax.random.PRNGKey(0),
                                              dict(regions=truth.regions, normals=normals))
        error = np.abs(fitted - target)[inner].mean()
        assert error < FITTED_SHADING_ERROR, (prompt, error)
        beyond = ~cv2.dilate(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        np.testing.assert_array_equal(fitted[beyond], truth.image[beyond])
        if "hair" in prompt or "eyebrows" in prompt:
            luminance = make_editor("semantic").edit(truth.image, truth.image, prompt,
                                                     jax.random.PRNGKey(0),
                                                     dict(regions=truth.regions))
            assert np.abs(luminance - target)[inner].mean() > 3 * error, prompt


def test_outline_jitter_scales_with_the_region_and_keeps_thin_regions_edited():
    """At noise 1 the outline between two wide regions grows and shifts by up to 4 px each, a
    3-px-wide region's by 3 / 16 of that; at the CLI's noise (0.3) the thin one is still edited over most of
    its pixels in most calls."""
    import cv2

    regions = np.full((80, 80), head.REGION_ID["skin"])
    regions[20:56, 20:56] = LIPS  # 36 px wide, in skin at least 20 px wide
    regions[36:39, 66:71] = head.REGION_ID["brows"]  # 3 px wide
    image = np.full((80, 80, 3), 0.6, np.float32)
    editor, default = make_editor("semantic", noise=1.0), make_editor("semantic", noise=0.3)
    cases = {LIPS: ("turn the lips blue", 4.0), head.REGION_ID["brows"]:
             ("make the eyebrows black", 4.0 * 3 / semantic.FULL_SIZE_THICKNESS)}
    for rid, (prompt, reach) in cases.items():
        inside = regions == rid
        distance = cv2.distanceTransform((~inside).astype(np.uint8), cv2.DIST_L2, 5)
        furthest, kept = [], []
        for k in range(24):
            for noisy, store in ((editor, furthest), (default, kept)):
                out = noisy.edit(image, image, prompt, jax.random.PRNGKey(k),
                                 dict(regions=regions))
                tone = out[0, 0] / image[0, 0]  # the global tone change, far from the regions
                changed = np.abs(out - image * tone).max(-1) > 0.05
                store.append(distance[changed].max() if store is furthest and changed.any()
                             else changed[inside].mean() if store is kept else 0.0)
        assert max(furthest) <= reach * (1 + np.sqrt(2)) + 1, (prompt, max(furthest))
        if rid == LIPS:
            assert max(furthest) >= 2  # the outline does move
        else:
            assert np.mean(np.asarray(kept) > 0.9) > 0.75, kept


def test_an_outline_moves_as_the_thinner_region_it_separates_and_the_silhouette_not_at_all():
    """A skin edit's outline moves by the skin's reach where it meets wide hair, by a 3-px lip
    strip's where it meets the lips (so the strip keeps most of its pixels), and never where it
    meets the background (the skin's last pixels before it are always edited)."""
    skin, hair = head.REGION_ID["skin"], head.REGION_ID["hair"]
    regions = np.full((64, 64), skin)
    regions[:, :4] = -1  # background
    regions[:, 44:] = hair  # 20 px wide
    regions[30:33, 14:34] = LIPS  # 3 px wide
    mask = regions == skin
    size = min(1.0, semantic.thickness(mask) / semantic.FULL_SIZE_THICKNESS)
    factor = semantic.border_size(regions, mask, size)
    assert size == 1.0
    assert factor[10, 4] == 0.0  # next to the background
    assert factor[10, 43] == pytest.approx(1.0)  # next to the hair
    lips = semantic.thickness(regions == LIPS) / semantic.FULL_SIZE_THICKNESS
    assert lips < 0.3 and factor[29, 20] == pytest.approx(lips)
    image = np.full((64, 64, 3), 0.6, np.float32)
    lips_kept, silhouette = [], []
    for k in range(24):
        for noise, store in ((0.3, lips_kept), (1.0, silhouette)):  # the CLI's noise; the most
            out = make_editor("semantic", noise=noise).edit(
                image, image, "make the skin blue", jax.random.PRNGKey(k), dict(regions=regions))
            tone = out[:, 0] / image[:, 0]  # the global tone change, in the background
            change = np.abs(out - image * tone[:, None]).max(-1)
            changed = change > 0.5 * np.median(change[:, 44 - 8:44 - 4])  # over half the skin's
            store.append(1 - changed[regions == LIPS].mean() if store is lips_kept
                         else changed[:, 4].mean())
    assert np.mean(np.asarray(lips_kept) > 0.6) > 0.9, lips_kept
    # a partial edit (probability 0.25 at noise 1) may cut the silhouette off; otherwise whole
    assert np.mean(np.asarray(silhouette) == 1.0) > 0.6, silhouette


def test_stripes_follow_head_space_height():
    image, regions, _ = toy_render()
    canonical = np.zeros(image.shape, np.float32)
    canonical[..., 1] = np.linspace(0, 0.04, 12)[:, None]
    out = make_editor("semantic").edit(image, image, "add green stripes to the lips",
                                       jax.random.PRNGKey(0),
                                       dict(regions=regions, canonical=canonical))
    changed = np.abs(out - image).max(-1) > 1e-6
    lips = regions == LIPS
    y = canonical[..., 1]
    pixel = np.hypot(*np.gradient(y.astype(np.float64)))
    touched = instructions.stripe_distance(y, pixel) > -0.5  # some of the pixel on a stripe
    np.testing.assert_array_equal(changed, lips & touched)
    assert 0 < changed.sum() < lips.sum()


def test_stripe_distance_gives_a_pixels_share_of_the_stripes_as_supersampling_does():
    """Over pixels whose height rises linearly (by less than a stripe's width per pixel, any
    phase), clip(distance + 1/2) equals the share of 400 samples across each pixel that
    `stripe_on` puts on a stripe."""
    rng = np.random.default_rng(0)
    for slope, phase in ((0.0031, 0.0), (0.0007, 0.3), (0.0085, 0.75)):
        y0 = rng.uniform(0, 0.05)
        centres = y0 + slope * np.arange(40)
        samples = centres[:, None] + slope * (np.arange(400)[None, :] + 0.5 - 200) / 400
        share = instructions.stripe_on(samples, phase).mean(1)
        distance = instructions.stripe_distance(centres, np.full(40, slope), phase)
        np.testing.assert_allclose(np.clip(distance + 0.5, 0, 1), share, atol=0.01)
        np.testing.assert_array_equal(distance > 0, instructions.stripe_on(centres, phase))


def test_a_stripes_edge_pixel_takes_its_share_of_the_stripe_colour():
    """Noise-free, a lips pixel that a stripe's edge crosses becomes its stripe share of the
    recolour, the rest of it the image (the share from supersampling the height across it)."""
    image, regions, _ = toy_render()
    canonical = np.zeros(image.shape, np.float32)
    canonical[..., 1] = np.linspace(0.0013, 0.0413, 12)[:, None]
    y = canonical[..., 1].astype(np.float64)
    full = make_editor("semantic").edit(image, image, "turn the lips green",
                                        jax.random.PRNGKey(0), dict(regions=regions))
    out = make_editor("semantic").edit(image, image, "add green stripes to the lips",
                                       jax.random.PRNGKey(0),
                                       dict(regions=regions, canonical=canonical))
    step = y[1, 0] - y[0, 0]
    samples = y[..., None] + step * (np.arange(400) + 0.5 - 200) / 400
    share = instructions.stripe_on(samples).mean(-1)[..., None]
    lips = regions == LIPS
    inner = lips & np.roll(lips, 1, 0) & np.roll(lips, -1, 0)  # rows clear of the lips' outline
    assert ((share[inner] > 0.05) & (share[inner] < 0.95)).any()
    expected = share * full + (1 - share) * image
    np.testing.assert_allclose(out[inner], expected[inner], atol=0.01)


def test_multimodal_editor_puts_the_stripes_on_either_half_by_its_key():
    image, regions, _ = toy_render()
    canonical = np.zeros(image.shape, np.float32)
    canonical[..., 1] = np.linspace(0.001, 0.041, 12)[:, None]  # no row on a stripe's edge
    lips = regions == LIPS
    y = canonical[..., 1]
    pixel = np.hypot(*np.gradient(y.astype(np.float64)))
    # the rows some of whose pixel is on a stripe of each mode (phase 0 and 1/2)
    first = lips & (instructions.stripe_distance(y, pixel, 0.0) > -0.5)
    second = lips & (instructions.stripe_distance(y, pixel, 0.5) > -0.5)
    editor = make_editor("semantic", modes=2)
    context = dict(regions=regions, canonical=canonical)
    seen = []
    for k in range(12):
        key = jax.random.PRNGKey(k)
        out = editor.edit(image, image, "add green stripes to the lips", key, context)
        changed = np.abs(out - image).max(-1) > 1e-6
        np.testing.assert_array_equal(changed, first if editor.mode(key) == 0 else second)
        seen.append(editor.mode(key))
    assert 0 < sum(seen) < len(seen)  # both modes occur
    assert first.any() and second.any() and not (first & second).all()
    assert not (lips & instructions.stripe_on(y, 0.0) & instructions.stripe_on(y, 0.5)).any()
    one = make_editor("semantic").edit(image, image, "add green stripes to the lips",
                                       jax.random.PRNGKey(0), context)
    again = make_editor("semantic", modes=1).edit(image, image, "add green stripes to the lips",
                                                  jax.random.PRNGKey(0), context)
    np.testing.assert_array_equal(one, again)
    with pytest.raises(ValueError, match="modes must be"):
        make_editor("semantic", modes=0)


def test_multimodal_recolour_picks_a_dark_or_a_light_shade_by_its_key():
    image, regions, shade = toy_render()
    lips = regions == LIPS
    blue = np.array(instructions.COLOURS["blue"])
    shades = {0: 0.5 * blue, 1: blue + 0.5 * (1 - blue)}  # dark: half; light: halfway to white
    editor = make_editor("semantic", modes=2)
    seen = set()
    for k in range(10):
        key = jax.random.PRNGKey(k)
        out = editor.edit(image, image, "turn the lips blue", key, dict(regions=regions))
        mode = editor.mode(key)
        seen.add(mode)
        expected = shades[mode][None, :] * shade[lips][:, None]  # the lips' shading kept
        np.testing.assert_allclose(out[lips], expected, rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(out[~lips], image[~lips])
    assert seen == {0, 1}
    three = instructions.mode_of(instructions.parse("turn the lips blue"), 1, 3)[0].colour
    np.testing.assert_allclose(three, (shades[0] + shades[1]) / 2)  # the middle shade
    stripes = instructions.parse("add green stripes to the lips")
    assert instructions.mode_of(stripes, 1, 4) == (stripes, 0.25)
    with pytest.raises(ValueError, match="mode must be"):
        instructions.mode_of(stripes, 2, 2)


def test_ideal_of_the_other_mode_stripes_the_other_half_of_the_region():
    rng = np.random.default_rng(1)
    faces = np.arange(30).reshape(10, 3)
    face_regions = np.full(10, head.REGION_ID["skin"])
    rest = rng.uniform(-0.05, 0.05, (30, 3))
    albedo = np.full((30, 3), 0.5)
    instruction = instructions.parse("add green stripes to the skin")
    ideal = [instructions.ideal_albedo(instruction, albedo, faces, face_regions, rest, phase)
             for phase in (0.0, 0.5)]
    striped = [np.all(a == instruction.colour, -1) for a in ideal]
    y = 2 * np.pi * rest[:, 1] / instructions.STRIPE_PERIOD
    np.testing.assert_array_equal(striped[0], np.sin(y) > 0)
    np.testing.assert_array_equal(striped[1], np.sin(y) < 0)


@pytest.mark.parametrize("prompt", ["make it an oil painting", "a pencil sketch",
                                    "make it a cartoon", "stylize it like a watercolor"])
def test_style_editor_changes_the_image_and_depends_on_the_key(prompt):
    rng = np.random.default_rng(0)
    image = np.clip(rng.random((40, 48, 3)) * 0.2 + np.linspace(0, 0.8, 48)[None, :, None], 0, 1)
    editor = make_editor("style")
    a = editor.edit(image, image, prompt, jax.random.PRNGKey(0))
    b = editor.edit(image, image, prompt, jax.random.PRNGKey(7))
    assert a.shape == image.shape and a.dtype == np.float32 and 0 <= a.min() and a.max() <= 1
    assert np.abs(a - image).mean() > 0.01
    assert np.abs(a - b).max() > 0
    np.testing.assert_array_equal(a, editor.edit(image, image, prompt, jax.random.PRNGKey(0)))


def test_unknown_editor_and_missing_ip2p_folder_are_clear(tmp_path):
    with pytest.raises(ValueError, match="unknown editor"):
        make_editor("photoshop")
    with pytest.raises(FileNotFoundError, match="model_index.json"):
        make_editor("ip2p", folder=str(tmp_path / "nothing"))


def tiny_ip2p_pipeline(folder):
    """A randomly initialised InstructPix2Pix pipeline small enough for a CPU test."""
    torch = pytest.importorskip("torch")
    diffusers = pytest.importorskip("diffusers")
    transformers = pytest.importorskip("transformers")
    torch.manual_seed(0)
    unet = diffusers.UNet2DConditionModel(
        sample_size=8, in_channels=8, out_channels=4, layers_per_block=1,
        block_out_channels=(8, 16), down_block_types=("DownBlock2D", "CrossAttnDownBlock2D"),
        up_block_types=("CrossAttnUpBlock2D", "UpBlock2D"), cross_attention_dim=16,
        norm_num_groups=4, attention_head_dim=2)
    vae = diffusers.AutoencoderKL(
        in_channels=3, out_channels=3, latent_channels=4, block_out_channels=(8, 8),
        down_block_types=("DownEncoderBlock2D",) * 2, up_block_types=("UpDecoderBlock2D",) * 2,
        norm_num_groups=4)
    text = transformers.CLIPTextModel(transformers.CLIPTextConfig(
        hidden_size=16, intermediate_size=32, num_attention_heads=2, num_hidden_layers=2,
        vocab_size=300, max_position_embeddings=77))
    letters = [chr(c) for c in range(ord("a"), ord("z") + 1)]
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for ch in letters:
        vocab[ch] = len(vocab)
        vocab[ch + "</w>"] = len(vocab)
    (folder / "tok").mkdir(parents=True)
    (folder / "tok" / "vocab.json").write_text(json.dumps(vocab))
    (folder / "tok" / "merges.txt").write_text("#version: 0.2\n")
    tokenizer = transformers.CLIPTokenizer(str(folder / "tok" / "vocab.json"),
                                           str(folder / "tok" / "merges.txt"),
                                           model_max_length=77)
    pipe = diffusers.StableDiffusionInstructPix2PixPipeline(
        vae=vae, text_encoder=text, tokenizer=tokenizer, unet=unet,
        scheduler=diffusers.DDIMScheduler(), safety_checker=None, feature_extractor=None,
        requires_safety_checker=False)
    pipe.save_pretrained(str(folder / "pipe"))
    return str(folder / "pipe")


def test_ip2p_edits_with_a_tiny_local_pipeline(tmp_path):
    folder = tiny_ip2p_pipeline(tmp_path)
    editor = make_editor("ip2p", folder=folder, steps=3)
    rng = np.random.default_rng(1)
    render = rng.random((24, 32, 3)).astype(np.float32)
    original = rng.random((24, 32, 3)).astype(np.float32)
    a = editor.edit(render, original, "turn the lips blue", jax.random.PRNGKey(0))
    b = editor.edit(render, original, "turn the lips blue", jax.random.PRNGKey(0))
    c = editor.edit(render, original, "turn the lips blue", jax.random.PRNGKey(1))
    assert a.shape == render.shape and np.all(np.isfinite(a)) and 0 <= a.min() and a.max() <= 1
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0
    with pytest.raises(ValueError, match="differ in size"):
        editor.edit(render, original[:8], "x", jax.random.PRNGKey(0))


def test_on_the_outline_only_the_regions_share_of_a_pixel_is_recoloured():
    """A uniform region's outline pixels, part lips, part skin: the editor mattes each pixel's
    lips share from the image (the lips' colour known, the skin's seen two pixels out) and
    recolours that share only; inside, the plain recolour; beyond, the image."""
    regions = np.full((14, 16), head.REGION_ID["skin"])
    regions[5:10, 4:12] = LIPS
    lips_rgb, skin_rgb = np.asarray(head.ALBEDO["lips"]), np.asarray(head.ALBEDO["skin"])
    shade = 0.8
    image = np.where((regions == LIPS)[..., None], lips_rgb, skin_rgb) * shade
    image[4, 4:12] = (0.3 * lips_rgb + 0.7 * skin_rgb) * shade  # skin-labelled, 30 % lips
    image[5, 4:12] = (0.8 * lips_rgb + 0.2 * skin_rgb) * shade  # lips-labelled, 80 % lips
    normals = np.zeros(regions.shape + (3,), np.float32)
    normals[..., 2] = 1.0  # one normal: the fitted light is the image's one shade
    out = make_editor("semantic").edit(image, image, "turn the lips blue", jax.random.PRNGKey(0),
                                       dict(regions=regions, normals=normals))
    blue = np.asarray(instructions.COLOURS["blue"])
    # the matte counts in proportion as the region is thin (5 px wide here)
    matte = 1 - semantic.thickness(regions == LIPS) / semantic.FULL_SIZE_THICKNESS
    shares = semantic._matte(image.astype(np.float32), regions == LIPS,
                             np.broadcast_to(lips_rgb * shade, image.shape).astype(np.float32))
    np.testing.assert_allclose(shares[4, 6:10], 0.3, atol=1e-3)
    np.testing.assert_allclose(shares[5, 6:10], 0.8, atol=1e-3)
    np.testing.assert_allclose(shares[7, 6:10], 1.0)  # inside, off the outline: the labels
    # skin-labelled row: the plain edit leaves it, the matte recolours its lips share
    matted = (0.3 * blue + 0.7 * skin_rgb) * shade
    expected = matte * matted + (1 - matte) * image[4, 6]
    np.testing.assert_allclose(out[4, 6:10], np.tile(expected, (4, 1)), atol=2e-3)
    np.testing.assert_allclose(out[7, 6:10], np.tile(blue * shade, (4, 1)), atol=2e-3)
    np.testing.assert_allclose(out[:3], image[:3], atol=1e-6)


# Against the ray-cast ideal, the outline pixels' mean absolute error per channel may exceed the
# inside's by this much when the editor knows how much of each pixel the region covers: the
# region's colour and shading there are those of the nearest pixel inside, a pixel away (on
# the painted hair, another stroke).
OUTLINE_EXCESS_WITH_SAMPLES = 0.02


@pytest.mark.parametrize("size, distance, jaw_open, prompt", [
    (128, 0.68, 0.0, "turn the lips blue"), (128, 0.68, 0.0, "make the skin light blue"),
    (128, 0.68, 0.0, "make the hair blonde"), (192, 0.45, 0.8, "make the teeth yellow"),
    (192, 0.45, 0.8, "make the whites of the eyes dark red")])
def test_with_label_samples_the_outline_is_recoloured_as_the_supersampled_ideal(
        size, distance, jaw_open, prompt):
    """The MakeHuman head ray-cast with 2 x 2 rays per pixel (as the scene's truth), and its
    ideal edit the same way: given each ray's region (`samples`) and the normals, the edit of
    a pixel the outline crosses changes only the region's share of it, so the outline pixels
    come within `OUTLINE_EXCESS_WITH_SAMPLES` of the inside's error; with the centre labels
    alone they take all or nothing of the new colour, at least twice as far off. A thin
    region's light is judged on the pixels its rays cover whole (teeth, sclera), not on those
    it shares with a darker neighbour."""
    truth, normals, ideal_of = _makehuman_view(size, distance, jaw_open, supersample=2)
    instruction = instructions.parse(prompt)
    ideal = ideal_of(prompt)
    region = head.REGION_ID[instruction.region]
    share = (truth.samples == region).mean(-1)
    outline = (share > 0) & (share < 1)
    assert outline.sum() > 20
    errors = {}
    for name, context in (("samples", dict(regions=truth.regions, samples=truth.samples,
                                           normals=normals)),
                          ("centre", dict(regions=truth.regions, normals=normals))):
        out = make_editor("semantic").edit(truth.image, truth.image, prompt,
                                           jax.random.PRNGKey(0), context)
        errors[name] = float(np.abs(out - ideal)[outline].mean())
        errors[name + " inside"] = float(np.abs(out - ideal)[share == 1].mean())
        if name == "samples":
            untouched = share == 0
            np.testing.assert_array_equal(out[untouched], truth.image[untouched])
    assert errors["samples"] < errors["samples inside"] + OUTLINE_EXCESS_WITH_SAMPLES, errors
    assert errors["samples"] < 0.5 * errors["centre"], errors
    assert errors["samples inside"] <= errors["centre inside"] + 1e-3, errors


def test_share_distance_puts_a_straight_outline_where_the_rays_see_it_and_moves_it_whole():
    """A half-plane whose edge crosses pixel column 5 at 0.25 of its width (every ray of the
    columns before it hits, none after): the weight clip(d + 1/2, 0, 1) is the rays' share in
    every pixel; the field rises one pixel per pixel across the outline, so that shifting it by
    a third of a pixel moves a third of a pixel of coverage from column to column (the centre
    labels' field, flat at 1/2 on the pixels next to the outline, would not)."""
    k = 4
    fine = np.zeros((6 * k, 10 * k), bool)
    fine[:, :5 * k + 1] = True  # one of the 4 ray columns of pixel column 5
    hits = fine.reshape(6, k, 10, k).transpose(0, 2, 1, 3).reshape(6, 10, k * k)
    share = hits.mean(-1)
    d = semantic._share_distance(hits, share)
    np.testing.assert_allclose(np.clip(d + 0.5, 0, 1), share, atol=1e-6)
    np.testing.assert_allclose(d[:, 5], 0.25 - 0.5, atol=1e-6)
    np.testing.assert_allclose(np.diff(d[0, 2:9]), -1.0, atol=0.13)
    moved = np.clip(d + 1.0 / 3.0 + 0.5, 0, 1)  # the outline a third of a pixel further out
    np.testing.assert_allclose(moved[0, 5], 0.25 + 1 / 3, atol=1e-6)


def test_nearest_takes_the_colour_of_the_closest_pixel_the_region_covers_whole():
    rng = np.random.default_rng(3)
    pure = rng.random((20, 24)) < 0.08
    source = rng.random((20, 24, 3)).astype(np.float32)
    shade = rng.random((20, 24)).astype(np.float32)
    old, near = semantic._nearest(source, shade, pure, np.zeros_like(source), shade * 0)
    ys, xs = np.nonzero(pure)
    yy, xx = np.mgrid[:20, :24]
    distance = np.hypot(yy[..., None] - ys, xx[..., None] - xs)
    taken = np.argmax(np.all(source[ys, xs][None, None] == old[:, :, None], -1), -1)
    # the 5x5 chamfer mask finds a pixel within 0.1 px of the truly nearest one
    assert np.all(distance[yy, xx, taken] <= distance.min(-1) + 0.1)
    np.testing.assert_array_equal(near, shade[ys[taken], xs[taken]])
    fallback = np.full_like(source, 0.5)
    got, _ = semantic._nearest(source, shade, np.zeros_like(pure), fallback, shade)
    np.testing.assert_array_equal(got, fallback)


def test_a_steady_share_of_the_outline_stays_where_the_labels_put_it():
    """`_jitter` with steady 1 returns the unmoved weight whatever the key (but for the random
    half cut of a partial edit), with steady 0 the moved one, and between them their blend."""
    mask = np.zeros((30, 30), bool)
    mask[10:20, 8:22] = True
    distance = semantic._signed_distance(mask)
    clean = np.clip(distance + 0.5, 0, 1)
    reach = np.full(mask.shape, 1.5, np.float32)
    for k in range(6):
        keys = jax.random.split(jax.random.PRNGKey(k), 5)
        cut = float(jax.random.uniform(keys[2])) < 0.25
        moved = semantic._jitter(mask, reach, keys, 1.0, distance, steady=0.0)
        kept = semantic._jitter(mask, reach, keys, 1.0, distance, steady=1.0)
        half = semantic._jitter(mask, reach, keys, 1.0, distance, steady=0.5)
        if not cut:
            np.testing.assert_array_equal(kept, clean)
        np.testing.assert_allclose(half, 0.5 * (moved + kept), atol=1e-6)
        assert cut or np.abs(moved - clean).max() > 0.3  # the outline did move
