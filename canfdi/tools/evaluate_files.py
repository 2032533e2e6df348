"""The files an evaluation writes (`canfdi evaluate -o DIR`): its figure, detection delay and
isolation accuracy against fault-to-noise ratio, and its result as JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

__all__ = ["plot_evaluation", "write_evaluation"]


def write_evaluation(stem: Path, result: dict[str, Any]) -> list[str]:
    """The figure and the JSON of ``result`` as STEM.png and STEM.json (parent directories
    created); their names, which also go into ``result["files"]`` (after the JSON is written:
    the file does not name itself)."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    plot_evaluation(result, stem.with_suffix(".png"))
    stem.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    result["files"] = [str(stem.with_suffix(".png")), str(stem.with_suffix(".json"))]
    return result["files"]


def plot_evaluation(r: dict[str, Any], path: Path) -> None:
    """Detection delay and isolation accuracy against fault-to-noise ratio, as a PNG.

    Parameters
    ----------
    r : the result of canfdi.tools.evaluate.evaluate (its ``fault_list`` and ``by_fnr``).
    path : the PNG written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    faults = r["fault_list"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7.5, 7), sharex=True)
    det = [f for f in faults if f["delay"] is not None]
    missed = [f for f in faults if f["delay"] is None]
    ax1.scatter([f["fnr"] for f in det], [max(f["delay"], 0) + 1 for f in det], s=12,
                alpha=0.6, label="detected fault (delay + 1)")
    if missed:
        top = max([f["delay"] + 1 for f in det], default=10) * 2
        ax1.scatter([f["fnr"] for f in missed], [top] * len(missed), marker="x", color="red",
                    label="missed")
    centers, means, p95s, acc, rate = [], [], [], [], []
    for b in r["by_fnr"]:
        if not b["faults"]:
            continue
        c = math.sqrt(b["fnr_lo"] * b["fnr_hi"])
        centers.append(c)
        means.append(None if b["delay_mean_samples"] is None else b["delay_mean_samples"] + 1)
        p95s.append(None if b["delay_p95_samples"] is None else b["delay_p95_samples"] + 1)
        acc.append(b["isolation_accuracy"])
        rate.append(b["detection_rate"])

    def line(ax, xs, ys, **kw):
        pts = [(x, y) for x, y in zip(xs, ys, strict=True) if y is not None]
        if pts:
            ax.plot(*zip(*pts, strict=True), marker="o", **kw)

    line(ax1, centers, means, color="black", label="bin mean")
    line(ax1, centers, p95s, color="gray", linestyle="--", label="bin 95th percentile")
    ax1.set_xscale("log")
    ax1.set_yscale("log")
    ax1.set_ylabel("detection delay + 1 (samples)")
    ax1.legend(fontsize=8)
    ax1.grid(True, which="both", alpha=0.3)
    ax1.set_title(f"canfdi evaluate: {r['plant']}, {r['method']}, {r['runs']} runs")
    line(ax2, centers, acc, color="tab:green", label="isolation accuracy (of accepted)")
    line(ax2, centers, rate, color="tab:blue", linestyle="--", label="detection rate")
    for lo in [b["fnr_lo"] for b in r["by_fnr"]] + [r["by_fnr"][-1]["fnr_hi"]]:
        ax2.axvline(lo, color="gray", alpha=0.2)
    ax2.set_ylim(-0.05, 1.05)
    ax2.set_xscale("log")
    ax2.set_xlabel("fault-to-noise ratio (residual noise standard deviations)")
    ax2.set_ylabel("fraction of faults")
    ax2.legend(fontsize=8, loc="lower right")
    ax2.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
