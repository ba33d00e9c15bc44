"""Paper 000 Fig. 9: success rate and displacement ratio per terrain and difficulty, the
planners side by side."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from qz_drake.experiments.worlds import DIFFICULTIES, TERRAINS  # noqa: E402


def plot_fig9(rows: list[dict], path, *, title: str = "") -> Path:
    """Two bar charts from ``summarise`` rows; a missing value (no successes) is left blank and
    labelled, not drawn as zero."""
    planners = sorted({r["planner"] for r in rows})
    groups = [(t, d) for t in TERRAINS for d in DIFFICULTIES
              if any((r["terrain"], r["difficulty"]) == (t, d) for r in rows)]
    fig, axes = plt.subplots(2, 1, figsize=(max(6.0, 1.1 * len(groups) + 2), 6.5), sharex=True)
    width = 0.8 / max(len(planners), 1)
    x = np.arange(len(groups))
    for ax, key, label in ((axes[0], "success_rate", "success rate"),
                           (axes[1], "displacement_ratio", "displacement ratio\n(walked / straight, successes)")):
        for i, planner in enumerate(planners):
            values = []
            for group in groups:
                row = next((r for r in rows if (r["terrain"], r["difficulty"], r["planner"]) == (*group, planner)), None)
                values.append(np.nan if row is None or row[key] is None else row[key])
            pos = x - 0.4 + width * (i + 0.5)
            bars = ax.bar(pos, np.nan_to_num(values), width, label=planner)
            for p, v, b in zip(pos, values, bars):
                ax.text(p, (0 if np.isnan(v) else v) + 0.01, "n/a" if np.isnan(v) else f"{v:.2f}",
                        ha="center", va="bottom", fontsize=7)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylim(0, 1.1)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].set_xticks(x, [f"{t}\n{d}" for t, d in groups], fontsize=8)
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
