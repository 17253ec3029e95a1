"""The GAN claim's scenario (the paper's second claim): an editor with two plausible answers
per call, the rows of the study, its sharpness metric and its summaries. `benchmarks/
gan_scenario.py` runs it; `experiments/gan_study.ipynb` reads it."""

from __future__ import annotations

import numpy as np

from gae_jax.evaluation import metrics, protocols, score
from gae_jax.run.bench import paired_change, save_figure
from gae_jax.scene import rig as rigs

PROMPT = "add green stripes to the skin"
COLOUR_PROMPT = "turn the lips blue"
REGION = {PROMPT: "skin", COLOUR_PROMPT: "lips"}
MODES = 2
LONG_ITERATIONS = 300
LONG_WEIGHTS = (0.0, 0.01, 0.1)
FAST_D_LR = 1e-3


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


def mode_scores(edited, evalsets: list, tile_capacity: int, blend, region: str = "skin") -> dict:
    """{protocol: {psnr_best, lpips_best, best_mode, psnr_mean_of_modes, sharpness}} of the
    edited avatar on `region` against each mode's ideal (`evalsets[m]`); `edited` None scores
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
        per_mode = [metrics.region_scores(ours, f.truth, regions, region) for f in frames]
        best = int(np.argmax([s["psnr"]["edited"] for s in per_mode]))
        skin = metrics.region_masks(regions, region)["edited"]
        ideal = frames[best].truth.astype(np.float64) / 255.0
        average = np.mean([f.truth.astype(np.float64) / 255.0 for f in frames], 0)
        out[name] = dict(
            best_mode=best, psnr_best=round(per_mode[best]["psnr"]["edited"], 3),
            lpips_best=round(per_mode[best]["lpips"]["edited"], 4),
            psnr_mean_of_modes=round(metrics.pooled_psnr(ours, average, skin), 3),
            sharpness=round(laplacian_energy(ours, eroded(skin))
                            / laplacian_energy(ideal, eroded(skin)), 3))
    return out


def adversarial(weight: float) -> dict:
    """EditConfig overrides for adversarial weight `weight` (lambda_2 = lambda_3; 0: GAN off)."""
    return dict(adversarial=False) if weight == 0 else dict(d_weight=weight, g_weight=weight)


def rows(weights, seeds) -> dict:
    """{row name: EditConfig field overrides}."""
    out = {}
    for seed in seeds:
        for w in weights:
            out[f"modes2/w{w:g}/seed{seed}"] = dict(editor_modes=MODES, seed=seed,
                                                   **adversarial(w))
    out["modes1/w0/seed0"] = dict(adversarial=False)
    out["modes1/w0.01/seed0"] = dict()
    for seed in seeds:
        for w in weights:
            out[f"colour2/w{w:g}/seed{seed}"] = dict(prompt=COLOUR_PROMPT, editor_modes=MODES,
                                                    seed=seed, **adversarial(w))
    for seed in seeds:
        for w in LONG_WEIGHTS:
            out[f"modes2/w{w:g}/seed{seed}/it{LONG_ITERATIONS}"] = dict(
                editor_modes=MODES, seed=seed, iterations=LONG_ITERATIONS,
                lr_decay_steps=LONG_ITERATIONS, **adversarial(w))
        out[f"modes2/w0.1/seed{seed}/dlr{FAST_D_LR:g}"] = dict(
            editor_modes=MODES, seed=seed, d_weight=0.1, g_weight=0.1, d_lr=FAST_D_LR)
    return out


def groups(weights, seeds) -> dict:
    """{summary label: ([row per seed], [the GAN-off row per seed, same iterations])}."""
    off = [f"modes2/w0/seed{s}" for s in seeds]
    out = {f"w {w:g}": ([f"modes2/w{w:g}/seed{s}" for s in seeds], off) for w in weights}
    long_off = [f"{r}/it{LONG_ITERATIONS}" for r in off]
    for w in LONG_WEIGHTS:
        out[f"w {w:g}, {LONG_ITERATIONS} it."] = (
            [f"modes2/w{w:g}/seed{s}/it{LONG_ITERATIONS}" for s in seeds], long_off)
    out[f"w 0.1, discriminator rate {FAST_D_LR:g}"] = (
        [f"modes2/w0.1/seed{s}/dlr{FAST_D_LR:g}" for s in seeds], off)
    colour_off = [f"colour2/w0/seed{s}" for s in seeds]
    for w in weights:
        out[f"lips colour, w {w:g}"] = ([f"colour2/w{w:g}/seed{s}" for s in seeds], colour_off)
    return out


def summary_lines(results: dict, weights, seeds) -> list:
    """Markdown: per group of `groups` with every row in `results`, seed means (min-max) and
    the paired change against the GAN off of the PSNR and the LPIPS against the better mode,
    each with its mean change over the larger of the two rows' seed ranges."""
    lines = ["", "Summary, seeds " + " / ".join(map(str, seeds)) + " (paired: the same seed "
             "with the GAN off at the same iterations; skin for the stripes, lips for the "
             "colour; ratio: mean change / larger seed range of the two rows):", "",
             "| rows | PSNR vs better mode (min-max) | paired PSNR change | ratio | LPIPS vs "
             "better mode | paired LPIPS change | ratio | PSNR vs mean of modes | sharpness | "
             "flicker (region) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for label, (names, off) in groups(weights, seeds).items():
        if not all(n in results for n in names + off):  # a study run with fewer rows
            continue
        recs, base = [results[n] for n in names], [results[n] for n in off]
        cells = []
        for field, digits in (("psnr_best", 2), ("lpips_best", 3)):
            ours = [mean(r, field) for r in recs]
            control = [mean(r, field) for r in base]
            change, spread = paired_change(ours, control)
            centre = f"{np.mean(ours):.{digits}f}"
            if field == "psnr_best":
                centre += f" ({min(ours):.2f}-{max(ours):.2f})"
            paired, ratio = "-", "-"
            if names != off:
                paired = (f"{np.mean(change):+.{digits}f} ("
                          + " / ".join(f"{c:+.{digits}f}" for c in change) + ")")
                ratio = f"{abs(np.mean(change)) / max(spread, 1e-6):.1f}"
            cells += [centre, paired, ratio]
        flicker = np.mean([r["evaluation"][p]["flicker"]["ours"]["edited"]
                           for r in recs for p in protocols.PROTOCOLS])
        lines.append(f"| {label} | " + " | ".join(cells) + " | "
                     f"{np.mean([mean(r, 'psnr_mean_of_modes') for r in recs]):.2f} | "
                     f"{np.mean([mean(r, 'sharpness') for r in recs]):.2f} | {flicker:.4f} |")
    return lines


def mean(record: dict, field: str):
    values = [record["modes"][p][field] for p in protocols.PROTOCOLS if p in record["modes"]]
    values = [v for v in values if v is not None]
    return round(float(np.mean(values)), 3) if values else None


def chart_tables(results: dict, weights, seeds) -> dict:
    """`chart`'s input: {scenario: [(weight, {field: per-seed values})]} of the 100-iteration
    two-mode rows."""
    fields = ("psnr_best", "psnr_mean_of_modes", "sharpness", "lpips_best")
    return {scenario: [(w, {f: [mean(results[f"{scenario}/w{w:g}/seed{s}"], f) for s in seeds]
                            for f in fields}) for w in weights]
            for scenario in ("modes2", "colour2")}


def chart(tables: dict, path: str) -> None:
    """Per scenario, PSNR against the better mode and against the mean of the modes per
    adversarial weight, the stripes' sharpness, and both LPIPS: `tables[scenario]` rows (weight, {field:
    per-seed values}); seed means with min-max bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def plot(axis, table, field, style, label=None, color=None):
        values = [np.asarray(r[1][field]) for r in table]
        centre = np.array([v.mean() for v in values])
        spread = np.array([[c - v.min() for v, c in zip(values, centre)],
                           [v.max() - c for v, c in zip(values, centre)]])
        axis.errorbar(np.arange(len(table)), centre, yerr=spread, fmt=style, capsize=3,
                      label=label, color=color)
        axis.set_xticks(np.arange(len(table)), [f"{w:g}" for w, _ in table])
        axis.set_xlabel("adversarial weight (lambda_2 = lambda_3)")

    fig, (a, b, c, d) = plt.subplots(1, 4, figsize=(17, 3.8))
    for axis, (scenario, title) in ((a, ("modes2", "green stripes, two phases: skin")),
                                    (c, ("colour2", "blue lips, dark or light: lips"))):
        plot(axis, tables[scenario], "psnr_best", "o-", "vs the better mode's ideal")
        plot(axis, tables[scenario], "psnr_mean_of_modes", "s--", "vs the mean of the two ideals")
        axis.set_ylabel("PSNR dB, mean over protocols")
        axis.set_title(title, fontsize=9)
        axis.legend(fontsize=8)
    plot(b, tables["modes2"], "sharpness", "o-", color="C2")
    b.axhline(1.0, color="k", ls=":", lw=0.8)
    b.set_ylabel("Laplacian energy, ours / ideal (skin)")
    b.set_title("stripes: sharpness (1: as sharp as an answer)", fontsize=9)
    plot(d, tables["modes2"], "lpips_best", "o-", "stripes (skin)", color="C2")
    plot(d, tables["colour2"], "lpips_best", "s-", "dark or light blue (lips)", color="C4")
    d.set_ylabel("LPIPS vs the better mode's ideal (lower: closer)")
    d.set_title("LPIPS", fontsize=9)
    d.legend(fontsize=8)
    fig.suptitle("Two-mode editors: does the GAN pick a mode or blur? (seed means, bars: min-max "
                 "over seeds)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
