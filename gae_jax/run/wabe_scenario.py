"""The WABE claim's scenario (the paper's first claim): a lips edit trained on closed-mouth
frames whose editor bleeds into the mouth, the rows of the study (methods x optimisers x
seeds, the beta sweep) and its claim arithmetic. `benchmarks/wabe_scenario.py` runs it;
`experiments/wabe_study.ipynb` reads it."""

from __future__ import annotations

import numpy as np

from gae_jax.edit.config import EditConfig
from gae_jax.run.bench import fmt, mean_over_protocols, paired_change, save_figure

PROMPT = "turn the lips blue"
# The first step's colour gradients, region none, standard blending, MakeHuman head (one SGD
# step at rate 1, seeds 0-3): 90th percentile 2.9e-4 to 3.4e-4 over the Gaussians that moved,
# median 1.1e-5 to 1.3e-5 (geometry's 90th percentiles 5e-6 to 9e-5): Adam's eps at that scale.
GRADIENT_EPS = 1e-4
# Adam's rates (1e-1 colours, 1e-3 geometry, 1e-4 positions) x 1000, the best of a probe on the
# row none/standard by its scores against the ideal (an oracle choice of the control's step
# size; lips 17.7 / 23.8 / 21.4 dB at x 100 / 1000 / 10000, whole 32.3 / 30.8 / 22.6: at 10000
# the geometry runs away).
SGD_RATES = dict(optimizer="sgd", lr=100.0, lr_geometry=1.0, lr_means=0.1)
METHODS = {"standard": dict(blend="standard"), "wabe_grad": dict(blend="wabe_grad"),
           "wabe": dict(blend="wabe"), "code_mask": dict(gradient_mask="code")}
OPTIMISERS = {"adam": {}, "adam_eps1e-15": dict(adam_eps=1e-15),
              f"adam_eps{GRADIENT_EPS:g}": dict(adam_eps=GRADIENT_EPS), "sgd": SGD_RATES}
BETAS = (0.0, 1.0, 3.0, 6.0, 10.0, 20.0)
SEEDS = (0, 1, 2)
LONG_ITERATIONS = 200
COMPARED = ("standard", "wabe_grad")  # the methods the claim compares, with their seeds


def rows(bleed: int) -> dict:
    """{row name: EditConfig field overrides}."""
    out = {}
    for opt_name, opt in OPTIMISERS.items():
        for method, knobs in METHODS.items():
            out[f"none/{method}/{opt_name}"] = dict(region="none", editor_bleed=bleed, **knobs,
                                                   **opt)
    for opt_name in ("adam", "sgd"):
        for method in COMPARED:
            out[f"prompt/{method}/{opt_name}"] = dict(region="prompt", editor_bleed=bleed,
                                                     **METHODS[method], **OPTIMISERS[opt_name])
            for name, seed in zip(seed_rows(method, opt_name)[1:], SEEDS[1:]):
                out[name] = dict(region="none", editor_bleed=bleed, seed=seed, **METHODS[method],
                                 **OPTIMISERS[opt_name])
        for beta in BETAS:
            if beta != EditConfig.beta:
                out[f"none/wabe_grad/{opt_name}/beta{beta:g}"] = dict(
                    region="none", editor_bleed=bleed, blend="wabe_grad", beta=beta,
                    **OPTIMISERS[opt_name])
    for method in COMPARED:  # a longer edit (rates decaying over it): less seed-to-seed spread?
        for name, seed in zip(seed_rows(method, "adam", f"/it{LONG_ITERATIONS}"), SEEDS):
            out[name] = dict(region="none", editor_bleed=bleed, seed=seed, **METHODS[method],
                             iterations=LONG_ITERATIONS, lr_decay_steps=LONG_ITERATIONS)
    out["prompt/standard/adam/no_bleed"] = dict(region="prompt", editor_bleed=0)
    out["none/standard/adam/no_bleed"] = dict(region="none", editor_bleed=0)
    return out


def seed_rows(method: str, opt_name: str, suffix: str = "") -> list:
    """The region-none rows of `method` and `opt_name` at seeds 0, 1, 2 (`suffix`: "/it200")."""
    base = f"none/{method}/{opt_name}"
    return [base + suffix] + [f"{base}/seed{s}{suffix}" for s in SEEDS[1:]]


def beta_row(opt_name: str, beta: float) -> str:
    base = f"none/wabe_grad/{opt_name}"
    return base if beta == EditConfig.beta else f"{base}/beta{beta:g}"


# (label, optimiser, row suffix) of the comparisons the claim rests on
CLAIMS = (("adam, 100 it.", "adam", ""), (f"adam, {LONG_ITERATIONS} it.", "adam",
                                          f"/it{LONG_ITERATIONS}"), ("sgd, 100 it.", "sgd", ""))
CLAIM_METRICS = (("psnr", "teeth", "teeth vs ideal"), ("change", "teeth", "teeth change"),
                 ("change", "tongue", "tongue change"))


def claim_lines(results: dict, claims=CLAIMS) -> list:
    """Markdown: per (label, optimiser, suffix) of `claims` whose rows are all in `results`,
    WABE on the gradient's gain over standard blending (region none) per seed and on the mean,
    against the larger of the two rows' seed ranges, for each of `CLAIM_METRICS`."""
    lines = ["", "WABE on the gradient against standard blending, region none, seeds "
             + " / ".join(map(str, SEEDS)) + " (dB):", "",
             "| comparison | metric | standard | WABE on the gradient | paired gain | mean gain "
             "| largest seed range | gain / range |", "|---|---|---|---|---|---|---|---|"]
    for label, opt_name, suffix in claims:
        names = {m: seed_rows(m, opt_name, suffix) for m in COMPARED}
        if not all(n in results for ns in names.values() for n in ns):
            continue
        for metric, region, title in CLAIM_METRICS:
            values = {m: [mean_over_protocols(results[r], metric, region) for r in names[m]]
                      for m in COMPARED}
            gains, spread = paired_change(values["wabe_grad"], values["standard"])
            lines.append(f"| {label} | {title} | " + " | ".join(
                " / ".join(fmt(x) for x in values[m]) for m in COMPARED)
                + f" | {' / '.join(f'{g:+.2f}' for g in gains)} | {np.mean(gains):+.2f} | "
                  f"{spread:.2f} | {abs(np.mean(gains)) / max(spread, 1e-3):.1f}x |")
    return lines


def chart(results: dict, untouched_teeth: float, path: str) -> None:
    """Left: teeth vs ideal per method (bars) and optimiser (groups), region none. Right: teeth
    and lips against WABE's beta, Adam and SGD."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.2),
                                      gridspec_kw=dict(width_ratios=[1.4, 1]))
    x = np.arange(len(OPTIMISERS))
    width = 0.8 / len(METHODS)
    for i, method in enumerate(METHODS):
        teeth = [mean_over_protocols(results[f"none/{method}/{o}"], "psnr", "teeth")
                 for o in OPTIMISERS]
        left.bar(x + (i - (len(METHODS) - 1) / 2) * width, teeth, width, label=method,
                 color=f"C{i}")
    left.axhline(untouched_teeth, color="k", ls="--", lw=0.8, label="untouched avatar")
    ours = mean_over_protocols(results["prompt/standard/adam"], "psnr", "teeth")
    left.axhline(ours, color="C5", lw=1.2, label="ours: the prompt's region, standard, adam")
    left.set_xticks(x, list(OPTIMISERS), fontsize=8)
    left.set_ylabel("teeth PSNR dB vs ideal (mean over protocols)")
    left.set_title("Region none: does the lips edit leak into the teeth?", fontsize=9)
    left.set_ylim(0, 31)
    left.legend(fontsize=7, loc="upper left", ncol=3)
    for j, opt_name in enumerate(("adam", "sgd")):
        for metric, style in (("teeth", "-o"), ("edited", "--s")):
            values = [mean_over_protocols(results[beta_row(opt_name, b)], "psnr", metric)
                      for b in BETAS]
            right.plot(BETAS, values, style, color=f"C{j}", ms=4,
                       label=f"{'teeth' if metric == 'teeth' else 'lips'}, {opt_name}")
    right.axhline(untouched_teeth, color="k", ls="--", lw=0.8)
    right.set_xlabel("beta of WABE on the gradient (0 = standard blending)")
    right.set_ylabel("PSNR dB vs ideal")
    right.set_title("Beta sweep, region none", fontsize=9)
    right.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)
