"""Cost-map figures of paper 003 (section 2.1, Eq. 7-10; section 2.3, Fig. 13) written as PNG."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

# File stem, CostMap attribute path, colour-bar label, scale to display units.
_LAYERS = (
    ("slope", "body.slope", "slope [deg]", 180.0 / np.pi),
    ("roughness", "body.roughness", "roughness [m]", 1.0),
    ("step_height", "body.step_height", "step height [m]", 1.0),
    ("body_cost", "body_cost", "body cost (Eq. 10) [-]", 1.0),
)


def _extent(cost_map) -> tuple[float, float, float, float]:
    H, W = cost_map.shape
    x0, y0 = cost_map.origin
    res = cost_map.resolution
    return (x0 - res / 2, x0 + (W - 0.5) * res, y0 - res / 2, y0 + (H - 0.5) * res)


def _layer(cost_map, attribute: str) -> np.ndarray:
    value = cost_map
    for name in attribute.split("."):
        value = getattr(value, name)
    return np.asarray(value, dtype=float)


# Legend entry of the black cells.
BLOCKED_LABEL = "blocked (step higher than max_step_height)"


def _draw(ax, fig, image: np.ndarray, extent, label: str, title: str):
    # Blocked cells (inf) are drawn black so they read as walls, not as the top of the scale; a
    # legend entry says so.
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    masked = np.ma.masked_invalid(image)
    cmap = plt.get_cmap("viridis").with_extremes(bad="black")
    im = ax.imshow(masked, origin="lower", extent=extent, cmap=cmap, interpolation="nearest")
    ax.set_aspect("equal")
    # The colour bar in an axes beside the map, as tall as the map (not as the figure).
    cax = make_axes_locatable(ax).append_axes("right", size="4%", pad=0.1)
    fig.colorbar(im, cax=cax, label=label)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    if np.ma.getmaskarray(masked).any():
        ax.fill([], [], color="black", label=BLOCKED_LABEL)
        ax.legend(loc="upper right", fontsize=8)


def plot_cost_maps(cost_map, out_dir: str | Path, *, title: str = "") -> dict[str, Path]:
    """Writes slope, roughness, step-height and body-cost maps as ``<layer>.png`` in ``out_dir``.

    Returns:
        layer name -> PNG path.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    extent = _extent(cost_map)
    paths = {}
    for stem, attribute, label, scale in _LAYERS:
        fig, ax = plt.subplots(figsize=(7, 6))
        _draw(ax, fig, _layer(cost_map, attribute) * scale, extent, label,
              f"{title} {stem.replace('_', ' ')}".strip())
        fig.tight_layout()
        path = out_dir / f"{stem}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths[stem] = path
    return paths


def plot_cost_map_path(cost_map, path: str | Path, *, paths_xy: dict[str, np.ndarray] | None = None,
                       start_xy=None, goal_xy=None, title: str = "") -> Path:
    """The Eq. 16 cost (cheapest heading per cell) with body paths drawn over it (Fig. 13).

    Args:
        paths_xy: legend label -> (K, 2) world path [m]; several paths compare safety weights.
    """
    extent = _extent(cost_map)
    cost = np.min(cost_map.heading_cost(), axis=0)
    fig, ax = plt.subplots(figsize=(7, 6))
    _draw(ax, fig, cost, extent, "cost (Eq. 16, cheapest heading) [-]", title or "A* path")
    for (label, xy), colour in zip((paths_xy or {}).items(), ("r", "w", "m", "c", "y")):
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        if len(xy):
            ax.plot(xy[:, 0], xy[:, 1], "-", color=colour, lw=2, label=label)
    if start_xy is not None:
        ax.plot(start_xy[0], start_xy[1], "^", color="orange", ms=9, label="start")
    if goal_xy is not None:
        ax.plot(goal_xy[0], goal_xy[1], "*", color="orange", ms=12, label="goal")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


# -- static gait (paper 003 section 3-4) -----------------------------------------------------------
_LEG_COLOURS = {"LF": "tab:red", "RF": "tab:orange", "LB": "tab:blue", "RB": "tab:cyan"}


def plot_static_gait(heightmap, result, path: str | Path, *, title: str = "") -> Path:
    """Footholds of a searched static gait over the heightmap (Fig. 9 / Fig. 14): each leg's
    footholds in its colour, the body centre's path during the swings in white."""
    from qz_drake.robot.quadruped import LEGS

    h = np.asarray(heightmap.heights)
    H, W = h.shape
    x0, y0 = heightmap.origin
    res = heightmap.resolution
    extent = (x0 - res / 2, x0 + (W - 0.5) * res, y0 - res / 2, y0 + (H - 0.5) * res)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    im = ax.imshow(h, origin="lower", extent=extent, cmap="terrain", interpolation="nearest")
    fig.colorbar(im, ax=ax, label="height [m]")
    if result.start_feet is not None:
        feet = np.concatenate([np.asarray(result.start_feet)[None]] + [s.feet[None] for s in result.states])
        for i, leg in enumerate(LEGS):
            ax.plot(feet[:, i, 0], feet[:, i, 1], "o-", color=_LEG_COLOURS[leg], ms=5, lw=1, label=leg)
        body = np.array([result.start_p_WB] + [s.p_WB for s in result.states])
        ax.plot(body[:, 0], body[:, 1], ".-", color="w", lw=1.5, label="body")
    pad = 0.12
    if result.start_feet is not None:
        ax.set_xlim(feet[..., 0].min() - pad, feet[..., 0].max() + pad)
        ax.set_ylim(feet[..., 1].min() - pad, feet[..., 1].max() + pad)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.set_title(title or f"static gait: {result.reason}")
    ax.legend(loc="upper left", fontsize=7, ncol=5)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_search_tree(results: dict, path: str | Path, *, max_steps: int | None = None) -> Path:
    """The recursive backtracking search as a tree (Fig. 7), one panel per search depth.

    Args:
        results: panel title (e.g. "depth 1") -> GaitSearchResult made with ``record_tree``.
        max_steps: draw only the nodes of the first ``max_steps`` steps.

    Each checked candidate state is a marker at (step, visiting order): green the committed
    states, grey the states that passed the checks but were backtracked from, red crosses the
    rejected ones. Lines join a state to the candidates checked from it.
    """
    fig, axes = plt.subplots(1, len(results), figsize=(5.5 * len(results), 5), squeeze=False)
    for ax, (label, result) in zip(axes[0], results.items()):
        tree = result.tree or []
        nodes = [n for n in tree if max_steps is None or n.step < max_steps]
        keep = {n.index for n in nodes}
        y = {n.index: k for k, n in enumerate(nodes)}
        committed_by_step = {n.step: n.index for n in nodes if n.committed}
        for n in nodes:
            # A first-level node grows from the state committed at the step before.
            parent = n.parent if n.parent in keep else committed_by_step.get(n.step - 1)
            if parent is not None and parent in keep:
                ax.plot([n.step - 1, n.step], [y[parent], y[n.index]], "-", color="0.75", lw=0.5, zorder=1)
        for kind, colour, marker, size in (("rejected", "tab:red", "x", 12), ("backtracked", "0.45", "o", 10),
                                          ("committed", "tab:green", "o", 40)):
            pick = [n for n in nodes if (kind == "rejected" and not n.ok)
                    or (kind == "backtracked" and n.ok and not n.committed)
                    or (kind == "committed" and n.committed)]
            ax.scatter([n.step for n in pick], [y[n.index] for n in pick], c=colour, marker=marker, s=size,
                       label=f"{kind} ({len(pick)})", zorder=3 if kind == "committed" else 2)
        chain = sorted(committed_by_step.items())
        if chain:
            ax.plot([s for s, _ in chain], [y[i] for _, i in chain], "-", color="tab:green", lw=2, zorder=2)
        ax.invert_yaxis()
        ax.set_xlabel("step")
        ax.set_ylabel("candidate states in visiting order")
        ax.set_title(f"{label}: {'found' if result.success else result.reason}", fontsize=9)
        ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_depth_study(study, path: str | Path) -> Path:
    """Success rate of the static-gait search against search depth (Fig. 10 as numbers), one
    bar per depth of a :class:`~qz_drake.planning.depth_study.DepthStudy`."""
    depths = list(study.depths)
    rates = [study.success_rate[d] for d in depths]
    fig, ax = plt.subplots(figsize=(6, 4))
    bars = ax.bar([str(d) for d in depths], rates, color="tab:green", label="success")
    for bar, rate in zip(bars, rates):
        ax.text(bar.get_x() + bar.get_width() / 2, rate + 0.01, f"{rate:.0%}", ha="center", va="bottom")
    ax.set_ylim(0, 1.1)
    ax.set_xlabel("search depth (steps looked ahead)")
    ax.set_ylabel(f"success rate over {study.terrains} cuboid terrains")
    ax.set_title(f"static gait search, {study.steps} steps, cuboids up to {study.max_height * 100:g} cm")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_safety_weight_paths(cost_map, results: dict, path: str | Path, *, start_xy=None, goal_xy=None,
                             title: str = "") -> Path:
    """Fig. 13: A* body paths for several safety weights w2 (Eq. 17) over the cost map, each
    labelled with its length and mean cell cost; where the paths share cells the later ones are
    drawn dashed over the earlier ones.

    Args:
        results: safety weight -> AStarResult.
    """
    extent = _extent(cost_map)
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    _draw(ax, fig, np.min(cost_map.heading_cost(), axis=0), extent, "cost (Eq. 16, cheapest heading) [-]",
          title or "A* body paths for two safety weights (Fig. 13)")
    styles = (("r", "-", 3.0), ("w", "--", 1.8), ("m", ":", 1.8), ("c", "-.", 1.8))
    for (weight, result), (colour, line, width) in zip(sorted(results.items()), styles):
        if result.found:
            ax.plot(result.xy[:, 0], result.xy[:, 1], line, color=colour, lw=width,
                    label=f"w2 = {weight:g}: {result.length:.1f} m, mean cost {result.mean_cell_cost:.3f}")
    if start_xy is not None:
        ax.plot(start_xy[0], start_xy[1], "^", color="orange", ms=9, label="start")
    if goal_xy is not None:
        ax.plot(goal_xy[0], goal_xy[1], "*", color="orange", ms=12, label="goal")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
