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


def _draw(ax, fig, image: np.ndarray, extent, label: str, title: str):
    # Blocked cells (inf) are drawn black so they read as walls, not as the top of the scale.
    masked = np.ma.masked_invalid(image)
    cmap = plt.get_cmap("viridis").with_extremes(bad="black")
    im = ax.imshow(masked, origin="lower", extent=extent, cmap=cmap, interpolation="nearest")
    fig.colorbar(im, ax=ax, label=label)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.set_aspect("equal")


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
