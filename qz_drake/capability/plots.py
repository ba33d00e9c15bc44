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


def plot_plan(heightmap, plan, path, *, title: str = "") -> Path:
    """Paper 000 Fig. 6(a): the utility of every cell (best over headings and topologies,
    warmer is higher) over the heightmap, and the most likely path from the start to the goal
    (markers where the topology changes)."""
    mdp = plan.mdp
    xmin, xmax, ymin, ymax = heightmap.bounds
    r = heightmap.resolution / 2
    fig, ax = plt.subplots(figsize=(8, 7 * (ymax - ymin + 2 * r) / max(xmax - xmin + 2 * r, 1e-9) + 1.0))
    ax.imshow(heightmap.heights, origin="lower", cmap="Greys_r", extent=(xmin - r, xmax + r, ymin - r, ymax + r))
    half = mdp.config.cell_size / 2
    utility = plan.utility_map()
    # The goal cell's states have arrived (V = 0 there): left transparent, the star marks it.
    utility[mdp.goal_cell[1], mdp.goal_cell[0]] = np.nan
    im = ax.imshow(utility, origin="lower", cmap="jet", alpha=0.55,
                   extent=(mdp.xs[0] - half, mdp.xs[-1] + half, mdp.ys[0] - half, mdp.ys[-1] + half))
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02, label="utility V (best heading and topology)")
    cells = plan.cells
    if len(cells):
        ax.plot(cells[:, 0], cells[:, 1], "w-", lw=2.5)
        ax.plot(cells[:, 0], cells[:, 1], "k-", lw=1)
        ax.plot(*cells[0], "wo", ms=9, mec="k", label="start")
    gx, gy = mdp.goal_cell
    ax.plot(mdp.xs[gx], mdp.ys[gy], "w*", ms=16, mec="k", label="goal")
    changes = [(s.x, s.y, s.action_topology) for s in plan.steps if s.topology != s.action_topology]
    for x, y, name in changes:
        ax.plot(x, y, "ms", ms=7, mec="k")
        ax.annotate(name, (x, y), textcoords="offset points", xytext=(5, 5), fontsize=8, color="m")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    outcome = f"P(success) {plan.success_probability:.2f}" if plan.reaches_goal else "goal not reached"
    ax.set_title(title or f"value iteration: {plan.solution.iterations} iterations, {len(plan.steps)} actions, "
                          f"{outcome}")
    ax.set_aspect("equal")
    return _save(fig, path)
