"""Matplotlib figures written as PNG (headless Agg backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from qz_drake.robot.kinematics import all_foot_positions  # noqa: E402
from qz_drake.robot.params import LEG_NAMES  # noqa: E402
from qz_drake.state_layout import BASE_POS, BASE_XY, BASE_Z, JOINT_Q, base_pose, tilt_deg  # noqa: E402


def draw_heightmap(fig, ax, heightmap, **colorbar) -> tuple:
    """A heightmap's top view on ``ax`` (colour = height, hill-shaded) with its colour bar;
    returns the image's extent (xmin, xmax, ymin, ymax) [m]."""
    h = np.asarray(heightmap.heights)
    xmin, xmax, ymin, ymax = heightmap.bounds
    r = heightmap.resolution / 2
    extent = (xmin - r, xmax + r, ymin - r, ymax + r)
    gy, gx = np.gradient(h, heightmap.resolution)
    shade = np.clip(0.5 + 0.5 * (-gx - gy) / np.sqrt(2), 0.0, 1.0)
    im = ax.imshow(h, origin="lower", extent=extent, cmap="terrain", interpolation="nearest")
    ax.imshow(shade, origin="lower", extent=extent, cmap="gray", alpha=0.25, interpolation="nearest")
    fig.colorbar(im, ax=ax, label="height [m]", **colorbar)
    return extent


def plot_heightmap(heightmap, path: str | Path, *, title: str = "", path_xy: np.ndarray | None = None,
                   start_xy=None) -> Path:
    """Top view of a heightmap (colour = height, hill-shaded) with an optional path."""
    h = np.asarray(heightmap.heights)
    fig, ax = plt.subplots(figsize=(7, 6))
    draw_heightmap(fig, ax, heightmap)
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
    z0 = info.initial_state[BASE_Z]
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    axes[0].plot(times, states[:, BASE_Z], label="base z")
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


def plot_walk(times, states, contacts, desired, log, info, out_dir: str | Path) -> dict:
    """Planned vs tracked base path and height, foot heights with contact phases, joint
    tracking error. Returns {name: path}."""
    out = Path(out_dir)
    files = {}
    planned = np.full((len(times), 3), np.nan)
    for plan in log.plans:
        for k, t in enumerate(times):
            if plan.start_time <= t:
                planned[k] = plan.base_position(min(t, plan.end_time))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    axes[0].plot(planned[:, 0], planned[:, 1], "k--", label="planned")
    axes[0].plot(*states[:, BASE_XY].T, "C0", label="tracked")
    targets = np.array([t[:2] for t in log.targets])
    axes[0].plot(targets[:, 0], targets[:, 1], "r^", label="mission targets")
    axes[0].set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[0].set_aspect("equal", adjustable="datalim")
    axes[0].legend()
    axes[1].plot(times, planned[:, 2], "k--", label="planned")
    axes[1].plot(times, states[:, BASE_Z], "C0", label="tracked")
    axes[1].set_xlabel("time [s]")
    axes[1].set_ylabel("base height [m]")
    axes[1].legend()
    fig.suptitle("base: planned vs tracked")
    fig.tight_layout()
    files["base_plot"] = str(out / "base_path.png")
    fig.savefig(files["base_plot"], dpi=100)
    plt.close(fig)

    feet = np.array([all_foot_positions(x[JOINT_Q], info.params) @ base_pose(x).rotation().matrix().T + x[BASE_POS]
                     for x in states])
    fig, axes = plt.subplots(6, 1, figsize=(10, 9), sharex=True)
    for i, leg in enumerate(LEG_NAMES):
        axes[i].plot(times, feet[:, i, 2], "C0")
        lo, hi = feet[:, i, 2].min(), feet[:, i, 2].max() + 1e-3
        axes[i].fill_between(times, lo, hi, where=contacts[:, i] > 0.5, color="g", alpha=0.2, step="post")
        axes[i].set_ylabel(leg)
    axes[-1].set_xlabel("time [s] (green: foot in contact)")
    fig.suptitle("foot heights [m] and contact phases")
    fig.tight_layout()
    files["feet_plot"] = str(out / "foot_heights.png")
    fig.savefig(files["feet_plot"], dpi=100)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(10, 3.5))
    error = np.degrees(np.abs(states[:, JOINT_Q] - desired[:, :18]))
    ax.plot(times, error.max(axis=1), label="max over joints")
    ax.plot(times, np.sqrt(np.mean(error**2, axis=1)), label="RMS over joints")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("joint tracking error [deg]")
    ax.legend()
    fig.tight_layout()
    files["joint_plot"] = str(out / "joint_tracking.png")
    fig.savefig(files["joint_plot"], dpi=100)
    plt.close(fig)
    return files
