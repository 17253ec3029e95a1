"""Does the temporal GAN fix a multimodal editor? (issue 15, the second claim)

    python benchmarks/gan_scenario.py [--weights 0 0.01 0.1 1] [--seeds 0 1 2] [--iterations 100]
                                      [--out benchmarks/results/gan_scenario]

The scenario where the paper says the GAN matters: the editor is inconsistent with several
plausible answers, not jitter around one. "add green stripes to the skin" with the built-in
editor at `--editor-modes 2`: each call puts the stripes on one of two halves of the skin
(stripe phase 0 or half a period, equally likely), besides its usual noise 0.3. L1 averages
the two answers: each stripe pixel is green in half the edits and skin in the other half.
Rows: the adversarial weight (lambda_2 = lambda_3 = w; 0 is the GAN off) x seeds, plus the
unimodal editor (`modes` 1) with and without the GAN for reference.

Scored per protocol against the ideal of each mode (`truth.build(..., phase=m / 2)`) on the
skin: PSNR and LPIPS against the better mode, PSNR against the mean of the two ideals (high:
the edit converged to their blur), and the sharpness ratio: the Laplacian's energy of ours
over that of the better mode's ideal on the skin pixels (1: as sharp as a real answer; the blur
of two opposite stripe patterns is flat: near 0); the skin's flicker on the held-out clip
(`score.evaluate_avatars`, against mode 0's truth). Writes `<out>.json` (resumable), `<out>.md`
and `<out>.png`.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from editbench import Bench, default_scene_and_avatar, fmt  # noqa: E402
from editbench import save_figure, write_report  # noqa: E402

from gae_jax.edit.config import EditConfig  # noqa: E402
from gae_jax.evaluation import metrics, protocols, score, truth  # noqa: E402
from gae_jax.scene import rig as rigs  # noqa: E402

PROMPT = "add green stripes to the skin"
MODES = 2


def laplacian_energy(images: np.ndarray, mask: np.ndarray) -> float:
    """Mean squared 4-neighbour Laplacian of (..., H, W, 3) images over the (..., H, W) mask
    (interior pixels only)."""
    x = np.asarray(images, np.float64)
    lap = (x[..., 1:-1, :-2, :] + x[..., 1:-1, 2:, :] + x[..., :-2, 1:-1, :]
           + x[..., 2:, 1:-1, :] - 4 * x[..., 1:-1, 1:-1, :])
    m = np.asarray(mask)[..., 1:-1, 1:-1]
    return float((lap ** 2).sum(-1)[m].mean()) if m.any() else float("nan")


def eroded(mask: np.ndarray, pixels: int = 2) -> np.ndarray:
    """(..., H, W) bool masks shrunk by `pixels` (so that the Laplacian at the skin's own outline
    -- eyes, brows, lips, hair -- does not count as the stripes' sharpness)."""
    import cv2

    m = np.asarray(mask, np.uint8).reshape((-1,) + mask.shape[-2:])
    kernel = np.ones((2 * pixels + 1,) * 2, np.uint8)
    return np.stack([cv2.erode(x, kernel) for x in m]).reshape(mask.shape).astype(bool)


def mode_scores(edited, evalsets: list, tile_capacity: int, blend) -> dict:
    """{protocol: {psnr_best, lpips_best, best_mode, psnr_mean_of_modes, sharpness}} of the
    edited avatar on the skin against each mode's ideal (`evalsets[m]`); `edited` None scores
    the mean of the ideals themselves (what a blur of the modes would be)."""
    render = rigs.make_view_renderer(blend)
    out = {}
    for name in evalsets[0].protocols:
        frames = [e.protocols[name][0] for e in evalsets]
        if edited is None:
            ours = np.mean([f.truth.astype(np.float32) / 255.0 for f in frames], 0)
        else:
            ours = score.render_frames(render, edited, evalsets[0], frames[0], tile_capacity)
        regions = frames[0].regions
        per_mode = [metrics.region_scores(ours, f.truth, regions, "skin") for f in frames]
        best = int(np.argmax([s["psnr"]["edited"] for s in per_mode]))
        skin = metrics.region_masks(regions, "skin")["edited"]
        ideal = frames[best].truth.astype(np.float64) / 255.0
        average = np.mean([f.truth.astype(np.float64) / 255.0 for f in frames], 0)
        out[name] = dict(
            best_mode=best, psnr_best=round(per_mode[best]["psnr"]["edited"], 3),
            lpips_best=round(per_mode[best]["lpips"]["edited"], 4),
            psnr_mean_of_modes=round(metrics.pooled_psnr(ours, average, skin), 3),
            sharpness=round(laplacian_energy(ours, eroded(skin))
                            / laplacian_energy(ideal, eroded(skin)), 3))
    return out


def rows(weights, seeds) -> dict:
    """{row name: EditConfig field overrides}."""
    out = {}
    for seed in seeds:
        for w in weights:
            gan = dict(adversarial=False) if w == 0 else dict(d_weight=w, g_weight=w)
            out[f"modes2/w{w:g}/seed{seed}"] = dict(editor_modes=MODES, seed=seed, **gan)
    out["modes1/w0/seed0"] = dict(adversarial=False)
    out["modes1/w0.01/seed0"] = dict()
    return out


def mean(record: dict, field: str):
    values = [record["modes"][p][field] for p in protocols.PROTOCOLS if p in record["modes"]]
    values = [v for v in values if v is not None]
    return round(float(np.mean(values)), 3) if values else None


def chart(table: list, path: str) -> None:
    """PSNR against the better mode, against the mean of the modes, and sharpness per adversarial
    weight: `table` rows (weight, {field: per-seed values}); seed means with min-max bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    def plot(axis, field, style, label=None, color=None):
        values = [np.asarray(r[1][field]) for r in table]
        centre = np.array([v.mean() for v in values])
        spread = np.array([[c - v.min() for v, c in zip(values, centre)],
                           [v.max() - c for v, c in zip(values, centre)]])
        axis.errorbar(x, centre, yerr=spread, fmt=style, capsize=3, label=label, color=color)

    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    labels = [f"{w:g}" for w, _ in table]
    x = np.arange(len(table))
    plot(a, "psnr_best", "o-", "vs the better mode's ideal")
    plot(a, "psnr_mean_of_modes", "s--", "vs the mean of the two ideals")
    a.set_xticks(x, labels)
    a.set_xlabel("adversarial weight (lambda_2 = lambda_3)")
    a.set_ylabel("skin PSNR dB, mean over protocols")
    a.legend(fontsize=8)
    plot(b, "sharpness", "o-", color="C2")
    b.axhline(1.0, color="k", ls=":", lw=0.8)
    b.set_xticks(x, labels)
    b.set_xlabel("adversarial weight")
    b.set_ylabel("Laplacian energy, ours / ideal")
    fig.suptitle("Stripes edit with a two-mode editor: does the GAN pick a mode or blur? "
                 "(seed means, bars: min-max over seeds)",
                 fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--weights", type=float, nargs="+", default=[0, 0.01, 0.1, 1])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--iterations", type=int, default=100)
    parser.add_argument("--out", default="benchmarks/results/gan_scenario")
    args = parser.parse_args()
    scene, original = default_scene_and_avatar()
    bench = Bench(args.out + ".json")
    evalsets = [truth.build(scene, PROMPT, frames=bench.frames, phase=m / MODES)
                for m in range(MODES)]
    lines = [f"# The GAN against a multimodal editor: \"{PROMPT}\", stripes on either half "
             f"({args.iterations} iterations)", "",
             "Skin, mean over the three protocols. Command: `python "
             "benchmarks/gan_scenario.py`.", "",
             "| row | PSNR vs better mode | PSNR vs mean of modes | LPIPS vs better mode | "
             "sharpness | flicker (skin) | edit s |", "|---|---|---|---|---|---|---|"]
    for name, overrides in rows(args.weights, args.seeds).items():
        config = dataclasses.replace(EditConfig(prompt=PROMPT, iterations=args.iterations),
                                     **overrides)
        extra: dict = {}

        def on_edited(avatar, extra=extra, config=config):
            session, _ = bench.session(config, scene, original)
            extra["modes"] = mode_scores(avatar, evalsets, session.rig.tile_capacity,
                                         session.step_config.blend)

        record = bench.run(name, config, scene, original, extra=extra, on_edited=on_edited)
        flicker = np.mean([record["evaluation"][p]["flicker"]["ours"]["edited"]
                           for p in protocols.PROTOCOLS])
        lines.append(f"| {name} | {fmt(mean(record, 'psnr_best'))} | "
                     f"{fmt(mean(record, 'psnr_mean_of_modes'))} | "
                     f"{fmt(mean(record, 'lpips_best'), 3)} | {fmt(mean(record, 'sharpness'))}"
                     f" | {flicker:.4f} | {record['edit_seconds']} |")
    session, _ = bench.session(EditConfig(prompt=PROMPT), scene, original)
    for label, avatar in (("untouched avatar", original), ("mean of the two ideals", None)):
        scores = {"modes": mode_scores(avatar, evalsets, session.rig.tile_capacity,
                                       session.step_config.blend)}
        if avatar is None:  # its PSNR against itself says nothing
            for p in scores["modes"].values():
                p["psnr_mean_of_modes"] = None
        lines.append(f"| {label} | {fmt(mean(scores, 'psnr_best'))} | "
                     f"{fmt(mean(scores, 'psnr_mean_of_modes'))} | "
                     f"{fmt(mean(scores, 'lpips_best'), 3)} | {fmt(mean(scores, 'sharpness'))}"
                     " | - | - |")
    table = []
    for w in args.weights:
        recs = [bench.results[f"modes2/w{w:g}/seed{s}"] for s in args.seeds]
        table.append((w, {f: [mean(r, f) for r in recs]
                          for f in ("psnr_best", "psnr_mean_of_modes", "sharpness")}))
    bench.save(iterations=args.iterations)
    write_report(args.out + ".md", "\n".join(lines) + "\n")
    chart(table, args.out + ".png")


if __name__ == "__main__":
    main()
