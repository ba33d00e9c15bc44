"""Paper 000 Fig. 9: success rate and displacement ratio per terrain and difficulty, the
planners side by side."""

from __future__ import annotations

import textwrap
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from qz_drake.experiments.worlds import DIFFICULTIES, PLANNER_NAMES, TERRAINS  # noqa: E402


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
    return _save(fig, path, dpi=120)


def _save(fig, path, dpi: int) -> Path:
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


# Colours of the planners in the pictures (others take matplotlib's cycle).
PLANNER_COLOURS = {"capplanner": "tab:red", "astar": "tab:blue", "astar_learned": "tab:green"}
# Line styles, so that two paths along the same route both show.
PLANNER_STYLES = {"capplanner": ("-", 3.0), "astar": ("--", 2.0), "astar_learned": (":", 2.0)}


def plot_task_pair(task, records: dict, path, *, title: str = "") -> Path:
    """One task's world (heights, hill-shaded) with each planner's walked path (a record's
    ``path_xy``), the start (triangle), the goal (star) and, for a walk that failed, where it
    stopped (a cross) with its reason; the legend says who walked."""
    from qz_drake.viz.plots import draw_heightmap

    fig, ax = plt.subplots(figsize=(9, 5.6))
    extent = draw_heightmap(fig, ax, task.heightmap, shrink=0.8)
    for planner, record in sorted(records.items()):
        colour = PLANNER_COLOURS.get(planner)
        name = PLANNER_NAMES.get(planner, planner)
        outcome = "walked" if record["success"] else f"failed: {record['reason'] or '?'}"
        points = np.asarray(record.get("path_xy") or [], dtype=float).reshape(-1, 2)
        if len(points):
            style, width = PLANNER_STYLES.get(planner, ("-", 2.0))
            line, = ax.plot(points[:, 0], points[:, 1], style, color=colour, lw=width, label=f"{name} ({outcome})")
            if not record["success"]:
                ax.plot(*points[-1], "x", color=line.get_color(), ms=14, mew=3)
                ax.annotate(record["reason"], points[-1], textcoords="offset points", xytext=(8, 8),
                            color=line.get_color(), fontsize=9, weight="bold")
        else:
            ax.plot([], [], "-", color=colour, lw=2,
                    label=f"{name} ({outcome}; {'no route' if record['reason'] == 'planner' else 'path not recorded'})")
    ax.plot(*task.start, "k^", ms=10, label="start")
    ax.plot(*task.goal, "k*", ms=14, label="goal")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.legend(loc="upper left", fontsize=8, framealpha=0.85)
    # Each failed walk's message, wrapped to the axes' width (two lines at most).
    messages = [line for p, rec in sorted(records.items()) if not rec["success"] and rec.get("message")
                for line in textwrap.wrap(f"{PLANNER_NAMES.get(p, p)}: {rec['message']}", width=100,
                                          max_lines=2, placeholder=" ...")]
    ax.set_title(title + ("\n" + "\n".join(messages) if messages else ""), fontsize=9)
    return _save(fig, path, dpi=110)
