"""Matplotlib figures written as PNG (headless Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from qz_drake.robot.params import LEG_NAMES  # noqa: E402


def plot_heightmap(heightmap, path: str | Path, *, title: str = "", path_xy: np.ndarray | None = None,
                   start_xy=None) -> Path:
    """Top view of a heightmap (colour = height, hill-shaded) with an optional path."""
    h = np.asarray(heightmap.heights)
    xmin, xmax, ymin, ymax = heightmap.bounds
    r = heightmap.resolution / 2
    extent = (xmin - r, xmax + r, ymin - r, ymax + r)
    fig, ax = plt.subplots(figsize=(7, 6))
    gy, gx = np.gradient(h, heightmap.resolution)
    shade = np.clip(0.5 + 0.5 * (-gx - gy) / np.sqrt(2), 0.0, 1.0)
    im = ax.imshow(h, origin="lower", extent=extent, cmap="terrain", interpolation="nearest")
    ax.imshow(shade, origin="lower", extent=extent, cmap="gray", alpha=0.25, interpolation="nearest")
    fig.colorbar(im, ax=ax, label="height [m]")
    if path_xy is not None:
        ax.plot(path_xy[:, 0], path_xy[:, 1], "r-", lw=2)
    if start_xy is not None:
        ax.plot(start_xy[0], start_xy[1], "k^", ms=9)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{h.shape[1]} x {h.shape[0]} cells, {heightmap.resolution} m")
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_standing(times, states, contacts, info, path: str | Path) -> Path:
    """Base height against nominal, tilt, and feet in contact over time."""
    from qz_drake.systems.state_layout import tilt_deg

    z0 = info.initial_state[6]
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    axes[0].plot(times, states[:, 6], label="base z")
    axes[0].axhline(z0, color="k", ls="--", lw=1, label="nominal")
    axes[0].fill_between(times, z0 - 0.02, z0 + 0.02, color="g", alpha=0.15, label="+-2 cm")
    axes[0].set_ylabel("height [m]")
    axes[0].legend(loc="lower right")
    axes[1].plot(times, [tilt_deg(x) for x in states])
    axes[1].set_ylabel("tilt [deg]")
    for i, leg in enumerate(LEG_NAMES):
        axes[2].fill_between(times, i + 0.1, i + 0.1 + 0.8 * contacts[:, i], step="post", alpha=0.8)
    axes[2].set_yticks(np.arange(6) + 0.5, LEG_NAMES)
    axes[2].set_ylabel("foot contact")
    axes[2].set_xlabel("time [s]")
    fig.suptitle(f"standing, topology {info.topology.name}")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)
