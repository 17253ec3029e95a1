"""A batch's summary: every job's scores in `summary.json`, a table in `summary.md` and a chart
in `summary.png`, rewritten (atomically) as jobs finish."""

from __future__ import annotations

import io
import json
import os

from gae_jax.util.fileio import atomic_write_bytes


def fmt(value, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def table(rows: list) -> str:
    """Markdown table of the rows (`runner.record`), in the given order."""
    lines = ["| job | state | prompt | seed | edited region dB | untouched dB | whole dB | "
             "seconds | settings |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        settings = ", ".join(f"{k}={v}" for k, v in r.get("settings", {}).items()) or "defaults"
        lines.append(f"| {r['name']} | {r['state']} | {r.get('prompt', '')} | "
                     f"{r.get('seed', '')} | {fmt(r.get('edited'))} | {fmt(r.get('untouched'))} "
                     f"| {fmt(r.get('whole'))} | {fmt(r.get('seconds'), 1)} | {settings} |")
    return "\n".join(lines)


def write(out: str, rows: list, meta: dict) -> None:
    """`out/summary.{json,md,png}` of the rows so far (failed jobs carry an `error`)."""
    atomic_write_bytes(os.path.join(out, "summary.json"),
                       json.dumps(dict(meta, jobs=rows), indent=1).encode())
    text = ["# Batch summary", "",
            f"`{meta.get('command', '')}`: {len(rows)} of {meta.get('jobs', len(rows))} jobs. "
            "PSNR dB against the ideal edit (the captured images on a user's data), mean over "
            "the three protocols; untouched: the original avatar's edited region.", "",
            table([r for r in rows if "error" not in r])]
    failed = [r for r in rows if "error" in r]
    if failed:
        text += ["", "## Failed", ""] + [f"- {r['name']}: {r['error']}" for r in failed]
    atomic_write_bytes(os.path.join(out, "summary.md"), ("\n".join(text) + "\n").encode())
    done = [r for r in rows if r.get("edited") is not None]
    if done:
        atomic_write_bytes(os.path.join(out, "summary.png"), chart(done))


def chart(rows: list) -> bytes:
    """PNG bytes: the edited region's PSNR per job, ours beside the untouched avatar."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(6.0, 0.5 * len(rows) + 2), 4.5))
    x = range(len(rows))
    ax.bar([i - 0.2 for i in x], [r["edited"] for r in rows], 0.4, label="edited avatar")
    ax.bar([i + 0.2 for i in x], [r["untouched"] or 0 for r in rows], 0.4, color="0.6",
           label="untouched avatar")
    ax.set_xticks(list(x), [r["name"] for r in rows], rotation=60, ha="right", fontsize=8)
    ax.set_ylabel("edited region, PSNR dB\n(mean of the 3 protocols)")
    ax.set_title("batch: every job's edited region against the ideal")
    top = max(max(r["edited"], r["untouched"] or 0) for r in rows)
    ax.set_ylim(0, 1.2 * top)  # room for the legend above the bars
    ax.legend(fontsize=8, ncol=2, loc="upper center")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return buffer.getvalue()
