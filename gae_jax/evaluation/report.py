"""The evaluation's results as a Markdown table (printed by the CLIs, written by evaluate)."""

from __future__ import annotations

from gae_jax.evaluation.protocols import PROTOCOLS

SUMMARY_COLUMNS = (("psnr", "whole"), ("psnr", "edited"), ("psnr", "teeth"), ("psnr", "eyes"),
                   ("psnr", "rest"), ("ssim", "whole"), ("ssim", "edited"), ("lpips", "whole"),
                   ("lpips", "edited"), ("drift", "whole"), ("change", "teeth"),
                   ("change", "iris"))


def summary_table(results: dict) -> str:
    """Markdown table of `score.evaluate_avatars`' results: a row per protocol and avatar."""
    head_cells = [f"{m.upper() if m not in ('drift', 'change') else m + ' PSNR'} {r}"
                  for m, r in SUMMARY_COLUMNS] + ["flicker", "CLIP-S",
                                                                      "CLIP-C"]
    lines = ["| protocol | avatar | " + " | ".join(head_cells) + " |",
             "|---" * (len(head_cells) + 2) + "|"]
    for name in PROTOCOLS:
        if name not in results:
            continue
        r = results[name]
        for who in ("ours", "original_avatar"):
            cells = [_cell(r[who].get(m, {}).get(k)) for m, k in SUMMARY_COLUMNS]
            cells.append(_cell(r["flicker"][who]["whole"]))
            cells += [_cell(r.get("clip_s")), _cell(r.get("clip_c"))] if who == "ours" else [
                "", ""]
            lines.append(f"| {name} | {who} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _cell(value) -> str:
    if value is None:
        return "-"
    return f"{value:.4f}" if abs(value) < 1 else f"{value:.2f}"
