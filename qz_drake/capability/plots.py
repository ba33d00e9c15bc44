"""Figures of the capability model (headless matplotlib, PNG): reliability diagrams and
confusion matrices of the networks on held-out scenes, and a map of the predicted success of
moving forward from every cell and heading, drawn over the heightmap (paper 000 Fig. 4's
transition model as the planner sees it)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _grid(count: int, columns: int = 3, size=(3.3, 3.1)):
    columns = max(1, min(columns, count))
    rows = int(np.ceil(count / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(size[0] * columns, size[1] * rows), squeeze=False)
    for ax in axes.ravel()[count:]:
        ax.axis("off")
    return fig, axes.ravel()[:count]


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_reliability(entries: list[dict], path, *, title: str = "") -> Path:
    """One reliability diagram per network: observed success rate against mean predicted
    probability per bin (marker area ~ trials in the bin), the diagonal, the ECE.

    ``entries``: dicts with ``name`` and the metrics of evaluation.binary_metrics.
    """
    fig, axes = _grid(max(1, len(entries)))
    for ax, entry in zip(axes, entries):
        rel = entry.get("reliability") or {"predicted": [], "observed": [], "count": []}
        ax.plot([0, 1], [0, 1], "k--", lw=0.8)
        if rel["predicted"]:
            counts = np.asarray(rel["count"], dtype=float)
            ax.plot(rel["predicted"], rel["observed"], "C0-", lw=1)
            ax.scatter(rel["predicted"], rel["observed"], s=20 + 200 * counts / counts.max(), color="C0", zorder=3)
        ece = entry.get("ece")
        ax.set_title(f"{entry['name']}\nn {entry.get('n', 0)}, ECE " + ("-" if ece is None else f"{ece:.3f}"),
                     fontsize=9)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.set_xlabel("predicted success", fontsize=8)
        ax.set_ylabel("observed success", fontsize=8)
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_confusion(entries: list[dict], path, *, title: str = "") -> Path:
    """One confusion matrix (at probability 0.5) per network; rows actual, columns predicted."""
    fig, axes = _grid(max(1, len(entries)), size=(2.9, 2.8))
    labels = ["fail", "success"]
    for ax, entry in zip(axes, entries):
        c = np.asarray(entry.get("confusion", [[0, 0], [0, 0]]))
        ax.imshow(c, cmap="Blues")
        for (i, j), n in np.ndenumerate(c):
            ax.text(j, i, str(n), ha="center", va="center", color="white" if n > c.max() / 2 else "black")
        ax.set_xticks([0, 1], labels, fontsize=8)
        ax.set_yticks([0, 1], labels, fontsize=8)
        ax.set_xlabel("predicted", fontsize=8)
        ax.set_ylabel("actual", fontsize=8)
        acc = entry.get("accuracy")
        ax.set_title(f"{entry['name']}: " + ("-" if acc is None else f"{100 * acc:.1f} %"), fontsize=9)
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_capability_map(heightmap, capability_map, path, *, topology: str | None = None, title: str = "") -> Path:
    """The heightmap in grey with, from every cell centre, eight arrows (one per heading)
    coloured by the predicted success of moving one cell forward along it."""
    index = 0 if topology is None else capability_map.topologies.index(topology)
    forward = capability_map.forward[index]  # (8, ny, nx)
    xmin, xmax, ymin, ymax = heightmap.bounds
    r = heightmap.resolution / 2
    fig, ax = plt.subplots(figsize=(8, 7 * (ymax - ymin + 2 * r) / max(xmax - xmin + 2 * r, 1e-9) + 1.5))
    im = ax.imshow(heightmap.heights, origin="lower", cmap="Greys_r",
                   extent=(xmin - r, xmax + r, ymin - r, ymax + r))
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, label="height [m]")
    gx, gy = np.meshgrid(capability_map.xs, capability_map.ys)
    angles = np.arange(8) * np.pi / 4
    length = 0.38 * capability_map.cell_size
    for k, angle in enumerate(angles):
        q = ax.quiver(gx, gy, np.full_like(gx, np.cos(angle) * length), np.full_like(gy, np.sin(angle) * length),
                      forward[k], cmap="RdYlGn", clim=(0.0, 1.0), angles="xy", scale_units="xy", scale=1,
                      width=0.004, headwidth=3, headlength=3)
    fig.colorbar(q, ax=ax, orientation="horizontal", fraction=0.046, pad=0.08,
                 label="P(success) of moving one cell forward (arrow: heading)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"predicted success, {capability_map.topologies[index]}")
    ax.set_aspect("equal")
    return _save(fig, path)


def plot_plan(heightmap, plan, path, *, title: str = "", walked_xy=None) -> Path:
    """Paper 000 Fig. 6(a) in two panels: left, the terrain (height colours, hill-shaded) with
    the most likely path; right, the utility of every cell (best over headings and
    topologies, brighter is better) under height contours, with the same path. Markers: start,
    goal, and where the topology changes (named). ``walked_xy`` (n, 2): the path the robot's
    trunk walked (paper 000 Fig. 6(b)), drawn over both panels. [m]"""
    mdp = plan.mdp
    xmin, xmax, ymin, ymax = heightmap.bounds
    r = heightmap.resolution / 2
    extent = (xmin - r, xmax + r, ymin - r, ymax + r)
    aspect = (ymax - ymin + 2 * r) / max(xmax - xmin + 2 * r, 1e-9)
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 5.2 * aspect + 0.8), sharex=True, sharey=True)
    h = np.asarray(heightmap.heights)
    gy, gx = np.gradient(h, heightmap.resolution)
    shade = np.clip(0.5 + 0.5 * (-gx - gy) / np.sqrt(2), 0.0, 1.0)
    terrain = left.imshow(h, origin="lower", extent=extent, cmap="terrain", interpolation="nearest")
    left.imshow(shade, origin="lower", extent=extent, cmap="gray", alpha=0.3, interpolation="nearest")
    fig.colorbar(terrain, ax=left, fraction=0.046, pad=0.02, label="height [m]")
    half = mdp.config.cell_size / 2
    utility = plan.utility_map()
    # The goal cell's states have arrived (V = 0 there): left blank, the star marks it.
    utility[mdp.goal_cell[1], mdp.goal_cell[0]] = np.nan
    im = right.imshow(utility, origin="lower", cmap="viridis", interpolation="nearest",
                      extent=(mdp.xs[0] - half, mdp.xs[-1] + half, mdp.ys[0] - half, mdp.ys[-1] + half))
    levels = np.linspace(np.nanmin(h), np.nanmax(h), 8)[1:-1]
    if np.ptp(h) > 1e-6:
        right.contour(h, levels=levels, origin="lower", extent=extent, colors="w", linewidths=0.5, alpha=0.6)
    fig.colorbar(im, ax=right, fraction=0.046, pad=0.02, label="utility V (best heading and topology)")
    cells = plan.cells
    gxi, gyi = mdp.goal_cell
    changes = [(s.x, s.y, s.action_topology) for s in plan.steps if s.topology != s.action_topology]
    for ax in (left, right):
        if len(cells):
            ax.plot(cells[:, 0], cells[:, 1], "w-", lw=3)
            ax.plot(cells[:, 0], cells[:, 1], "r-", lw=1.5, label="most likely path")
            ax.plot(*cells[0], "wo", ms=9, mec="k", label="start")
        if walked_xy is not None and len(walked_xy):
            walked = np.asarray(walked_xy, dtype=float).reshape(-1, 2)
            ax.plot(walked[:, 0], walked[:, 1], "k-", lw=2.5)
            ax.plot(walked[:, 0], walked[:, 1], "c-", lw=1.2, label="walked path")
        ax.plot(mdp.xs[gxi], mdp.ys[gyi], "y*", ms=16, mec="k", label="goal")
        for x, y, name in changes:
            ax.plot(x, y, "ms", ms=7, mec="k")
            ax.annotate(name, (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8, color="m",
                        fontweight="bold")
        ax.set_xlabel("x [m]")
        ax.set_aspect("equal")
    left.set_ylabel("y [m]")
    left.legend(loc="upper left", fontsize=8, framealpha=0.8)
    left.set_title("terrain and the planned path")
    outcome = (f"P(success) {plan.success_probability:.2f}, P(no fall) {plan.fall_free_probability:.2f}"
               if plan.reaches_goal else "goal not reached")
    right.set_title(f"VI: {plan.solution.iterations} iterations, {len(plan.steps)} actions, {outcome}")
    if title:
        fig.suptitle(title)
    return _save(fig, path)  # laid out there (a second tight_layout cost 50 ms, the same PNG)
