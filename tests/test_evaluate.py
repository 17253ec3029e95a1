"""Scores against independent references: pooled PSNR and masked SSIM by numpy loops, flicker in
closed form, the protocols' clips consecutive."""

import numpy as np
import pytest

from gae_jax import evaluate
from gae_jax.evaluation import lpips, metrics, protocols
from gae_jax.model import flame, head
from gae_jax.scene import synthetic
from tests.test_losses import naive_ssim


def test_region_scores_equal_numpy_references():
    rng = np.random.default_rng(0)
    truth = rng.random((2, 40, 36, 3))
    ours = np.clip(truth + rng.normal(scale=0.05, size=truth.shape), 0, 1)
    regions = np.full((2, 40, 36), head.REGION_ID["skin"])
    regions[:, 10:20, 5:30] = head.REGION_ID["lips"]
    regions[0, 25:30, 10:14] = head.REGION_ID["teeth"]
    scores = metrics.region_scores(ours, truth, regions, "lips")
    lips = regions == head.REGION_ID["lips"]
    mse = np.mean((ours[lips] - truth[lips]) ** 2)
    assert scores["psnr"]["edited"] == pytest.approx(10 * np.log10(1 / mse), abs=1e-3)
    ssim = np.stack([naive_ssim(o, t) for o, t in zip(ours, truth)]).mean(-1)
    assert scores["ssim"]["edited"] == pytest.approx(ssim[lips].mean(), abs=1e-4)
    teeth = regions == head.REGION_ID["teeth"]
    assert scores["ssim"]["teeth"] == pytest.approx(ssim[teeth].mean(), abs=1e-4)
    lp = np.asarray(lpips.lpips_map(ours, truth))
    assert scores["lpips"]["edited"] == pytest.approx(lp[lips].mean(), abs=1e-4)
    assert scores["psnr"]["eyes"] is None  # no eye pixels
    assert metrics.pooled_psnr(ours, truth) == pytest.approx(
        10 * np.log10(1 / np.mean((ours - truth) ** 2)), abs=1e-9)
    same = metrics.region_scores(truth, truth, regions, "lips")
    assert same["ssim"]["whole"] == pytest.approx(1.0, abs=1e-5)
    assert same["lpips"]["whole"] == pytest.approx(0.0, abs=1e-5)


def test_rest_is_the_head_without_background_and_whole_is_everything():
    regions = np.array([[-1, head.REGION_ID["skin"], head.REGION_ID["lips"]],
                        [head.REGION_ID["hair"], head.REGION_ID["teeth"], -1]])
    masks = metrics.region_masks(regions, "lips")
    assert masks["whole"].all()
    np.testing.assert_array_equal(masks["rest"], [[False, True, False], [True, False, False]])
    np.testing.assert_array_equal(masks["edited"], regions == head.REGION_ID["lips"])
    np.testing.assert_array_equal(masks["teeth"], regions == head.REGION_ID["teeth"])


def test_flicker_closed_form():
    rng = np.random.default_rng(1)
    truth = rng.random((5, 8, 8, 3))
    drift = truth + 0.01 * np.arange(5).reshape(5, 1, 1, 1)  # steady change: 0.01 per frame
    assert metrics.flicker(drift, truth) == pytest.approx(0.01)
    blink = truth + 0.02 * (np.arange(5) % 2).reshape(5, 1, 1, 1)  # +-0.02 every frame
    assert metrics.flicker(blink, truth) == pytest.approx(0.02)
    assert metrics.flicker(truth + 0.3, truth) == pytest.approx(0.0, abs=1e-12)
    mask = np.zeros((5, 8, 8), bool)
    mask[:, :4] = True
    local = truth.copy()
    local[::2, :4] += 0.1
    assert metrics.flicker(local, truth, mask) == pytest.approx(0.1)
    with pytest.raises(ValueError, match="T >= 2"):
        metrics.flicker(truth[:1], truth[:1])


def test_temporal_clips_are_consecutive_frames_at_one_camera(tmp_path):
    scene = synthetic.make_synthetic_scene(size=16, num_cameras=4, frames_per_sequence=3,
                                      supersample=1, progress=False, cache_dir=str(tmp_path))
    for name in protocols.PROTOCOLS:
        clip = protocols.temporal_frames(scene, name)
        seqs = {s for s, _ in clip.pairs}
        assert len(seqs) == 1 and [t for _, t in clip.pairs] == list(range(3))
        assert len(clip.cameras) == 1
    assert protocols.temporal_frames(scene, "novel_view").cameras == scene.held_out_cameras
    with pytest.raises(ValueError, match="unknown protocol"):
        protocols.temporal_frames(scene, "nope")


def test_ideal_of_a_colour_mode_paints_the_region_that_shade_and_nothing_else(tmp_path):
    from gae_jax import instructions
    from gae_jax.evaluation import truth

    scene = synthetic.make_synthetic_scene(size=16, num_cameras=4, frames_per_sequence=3,
                                           supersample=1, progress=False,
                                           cache_dir=str(tmp_path))
    lips = instructions.region_vertices(scene.model.faces, scene.face_regions, "lips",
                                        len(scene.albedo["A"]))
    blue = np.array(instructions.COLOURS["blue"])
    for mode, colour in ((0, 0.5 * blue), (1, 0.5 + 0.5 * blue)):
        instruction, albedo = truth.ideal_albedo(scene, "turn the lips blue", mode, 2)
        np.testing.assert_allclose(albedo[lips], np.broadcast_to(colour, albedo[lips].shape))
        np.testing.assert_array_equal(albedo[~lips], scene.albedo["A"][~lips])
        assert instruction.region == "lips"
    _, single = truth.ideal_albedo(scene, "turn the lips blue")
    np.testing.assert_allclose(single[lips], np.broadcast_to(blue, single[lips].shape))


def test_evaluate_cli_refuses_a_folder_that_is_not_a_run(tmp_path, capsys):
    assert evaluate.main([str(tmp_path)]) == 2
    assert "metrics.json not found" in capsys.readouterr().err


def test_drift_is_psnr_against_the_untouched_render_outside_the_dilated_edit():
    rng = np.random.default_rng(1)
    untouched = rng.random((2, 30, 30, 3))
    ours = untouched.copy()
    regions = np.full((2, 30, 30), head.REGION_ID["skin"])
    regions[:, :, :3] = -1
    regions[:, 10:14, 10:20] = head.REGION_ID["lips"]
    regions[:, 22:25, 10:20] = head.REGION_ID["teeth"]
    outside = metrics.outside_edit(regions, "lips", dilate=3)
    lips = regions == head.REGION_ID["lips"]
    # Outside = farther than 3 px (Chebyshev) from every lips pixel, by a loop.
    ys, xs = np.nonzero(lips[0])
    for y in range(30):
        for x in range(30):
            far = np.max(np.abs(np.stack([ys - y, xs - x])), 0).min() > 3
            assert outside[0, y, x] == far
    ours[lips] = 0.0  # the edit itself does not count
    ours[:, 11, 7:10] += 0.1  # 1-3 px from the lips: inside the dilation, not counted
    assert metrics.drift_scores(ours, untouched, regions, "lips")["whole"] == 99.0
    teeth = regions == head.REGION_ID["teeth"]
    ours[teeth] = np.clip(ours[teeth] + 0.05, 0, 1)
    drift = metrics.drift_scores(ours, untouched, regions, "lips")
    mse_teeth = np.mean((ours[teeth] - untouched[teeth]) ** 2)
    assert drift["teeth"] == pytest.approx(10 * np.log10(1 / mse_teeth), abs=1e-3)
    mse_all = np.mean((ours[outside] - untouched[outside]) ** 2)
    assert drift["whole"] == pytest.approx(10 * np.log10(1 / mse_all), abs=1e-3)
    assert drift["background"] == 99.0 and drift["eyes"] is None
    style = metrics.outside_edit(regions, None, dilate=0)
    np.testing.assert_array_equal(style, regions < 0)


def test_change_counts_every_visible_pixel_of_an_occluded_region_the_edits_border_included():
    rng = np.random.default_rng(2)
    untouched = rng.random((2, 30, 30, 3))
    regions = np.full((2, 30, 30), head.REGION_ID["skin"])
    regions[:, 10:14, 10:20] = head.REGION_ID["lips"]
    regions[:, 14:16, 10:20] = head.REGION_ID["teeth"]  # right under the lips: inside the
    regions[0, 20:22, 3:5] = head.REGION_ID["iris"]      # drift's dilation
    regions[0, 21, 4] = head.REGION_ID["pupil"]
    ours = untouched.copy()
    ours[regions == head.REGION_ID["lips"]] = 0.0  # the edit itself
    assert metrics.change_scores(ours, untouched, regions, "lips") == dict(
        teeth=99.0, tongue=None, iris=99.0)
    teeth = regions == head.REGION_ID["teeth"]
    ours[teeth] = np.clip(ours[teeth] * 0.5 + 0.4, 0, 1)  # the blue leaks into the teeth
    eye = np.isin(regions, [head.REGION_ID["iris"], head.REGION_ID["pupil"]])
    ours[eye] += 0.02
    change = metrics.change_scores(ours, untouched, regions, "lips")
    mse = np.mean((ours[teeth] - untouched[teeth]) ** 2)
    assert change["teeth"] == pytest.approx(10 * np.log10(1 / mse), abs=1e-3)
    assert change["iris"] == pytest.approx(10 * np.log10(1 / 0.02 ** 2), abs=1e-3)
    assert metrics.drift_scores(ours, untouched, regions, "lips")["teeth"] is None  # unseen
    assert metrics.change_scores(ours, untouched, regions, "iris")["iris"] == pytest.approx(
        10 * np.log10(1 / 0.02 ** 2), abs=1e-3)  # the pupil alone, the iris being edited
    assert metrics.change_scores(ours, untouched, regions, "teeth")["teeth"] is None


def test_scoring_refuses_a_tile_capacity_that_would_drop_gaussians():
    from gae_jax.evaluation import score

    with pytest.raises(ValueError, match="tile_capacity must be >= 1"):
        score.evaluate_avatars(None, None, None, tile_capacity=0)


def test_the_ideal_stripes_are_decided_per_ray_from_the_rest_height(tmp_path):
    """The stripes' truth: where the hit face is the region and the rest-pose height
    interpolated at the hit is on a stripe, the shaded stripe colour, else the shaded original
    (checked at one ray per pixel against the same rays cast with the two colourings and the
    height as plain vertex colours)."""
    import dataclasses

    from gae_jax import instructions
    from gae_jax.evaluation import truth
    from gae_jax.scene import raycast

    scene = synthetic.make_synthetic_scene(size=48, num_cameras=9, frames_per_sequence=2,
                                           progress=False, cache_dir=str(tmp_path))
    one_ray = dataclasses.replace(scene, supersample=1)
    prompt = "add green stripes to the skin"
    instruction, ideal = truth.ideal_of(one_ray, prompt)
    frames = truth.frames_truth(one_ray, protocols.protocol_frames(one_ray, "novel_view", 1),
                                ideal)
    name, t = frames.pairs[0]
    verts = np.asarray(flame.lbs(scene.model, scene.sequences[name].params(
        scene.shapes["A"], t)))
    camera = scene.camera(frames.cameras[0])
    faces = np.asarray(scene.model.faces)

    def cast(values):
        return raycast.raycast(verts, faces, values, scene.face_regions, camera,
                               background=scene.background)

    plain = cast(ideal.values[:, :3])
    paint = cast(ideal.values[:, 3:6]).image
    height = cast(np.repeat(ideal.values[:, 6:7], 3, 1)).image[..., 0]
    on = (plain.regions == head.REGION_ID["skin"]) & instructions.stripe_on(height)
    expected = np.where(on[..., None], paint, plain.image)
    expected = (np.clip(expected, 0, 1) * 255 + 0.5).astype(np.uint8)
    got = frames.truth[0, 0]
    assert on.sum() > 50 and (plain.regions == head.REGION_ID["skin"]).sum() > on.sum() + 50
    assert np.mean(np.abs(got.astype(int) - expected.astype(int)) <= 1) > 0.999
