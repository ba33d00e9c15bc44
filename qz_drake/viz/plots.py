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


# The longest stretch of a walk whose contact phases are drawn step by step: a tripod cycle is
# 0.8 s, so 8 s shows ten of them; over a whole 110 s walk, one shaded band per contact merged
# into a solid block.
CONTACT_WINDOW = 8.0  # [s]


def contact_window(times, foot_z, window: float = CONTACT_WINDOW) -> tuple[float, float]:
    """The stretch (start, end) [s] of a walk whose contact phases plot_foot_heights draws: all of
    it when it is at most ``window`` long, else ``window`` around the moment a foot is highest
    (the walk's steepest climb), inside the walk."""
    start, end = float(times[0]), float(times[-1])
    if end - start <= window:
        return start, end
    highest = float(times[np.unravel_index(int(np.argmax(foot_z)), foot_z.shape)[0]])
    first = min(max(highest - window / 2, start), end - window)
    return first, first + window


def plot_foot_heights(times, foot_z, contacts, path: str | Path, window: float = CONTACT_WINDOW) -> Path:
    """Each foot's height, shaded where it is in contact, one row per leg. ``foot_z`` (N, 6) [m],
    ``contacts`` (N, 6) 1 in contact. A walk longer than ``window`` gets an overview of its
    whole length on top (the heights of the feet in contact, i.e. the ground under the robot, and
    up to the highest foot; the stretch below marked) and its rows show the stretch of
    contact_window, where each step reads on its own."""
    times, foot_z, contacts = np.asarray(times), np.asarray(foot_z), np.asarray(contacts)
    first, last = contact_window(times, foot_z, window)
    whole = first <= times[0] and last >= times[-1]
    rows = 6 if whole else 7
    fig, axes = plt.subplots(rows, 1, figsize=(10, 9 if whole else 10.5), sharex=False,
                             gridspec_kw={"height_ratios": [1] * 6 if whole else [1.6] + [1] * 6})
    leg_axes = axes if whole else axes[1:]
    if not whole:
        overview = axes[0]
        # Over one second (more than a tripod cycle) at each sample, so that a band follows the
        # terrain rather than every step.
        from scipy.ndimage import maximum_filter1d, minimum_filter1d

        second = max(1, int(round(1.0 / max(float(np.median(np.diff(times))), 1e-6))))
        in_contact = contacts > 0.5
        low = minimum_filter1d(np.where(in_contact, foot_z, np.inf).min(axis=1), second)
        high = maximum_filter1d(np.where(in_contact, foot_z, -np.inf).max(axis=1), second)
        highest = maximum_filter1d(foot_z.max(axis=1), second)
        low, high = np.where(np.isfinite(low), low, np.nan), np.where(np.isfinite(high), high, np.nan)
        overview.fill_between(times, low, highest, color="C0", alpha=0.2, lw=0,
                              label="feet in the air, up to the highest")
        overview.fill_between(times, low, high, color="g", alpha=0.6, lw=0, label="feet in contact")
        overview.axvspan(first, last, color="0.5", alpha=0.3, lw=0)
        overview.set_xlim(times[0], times[-1])
        overview.set_ylabel("height [m]")
        overview.set_title(f"the whole walk; below, {first:.0f}-{last:.0f} s (grey), where a foot is highest",
                           fontsize=10)
        overview.legend(ncol=2, fontsize=8, loc="upper left")
    shown = (times >= first) & (times <= last)
    for i, leg in enumerate(LEG_NAMES):
        ax = leg_axes[i]
        z = foot_z[shown, i]
        ax.plot(times[shown], z, "C0")
        lo, hi = z.min(), z.max() + 1e-3
        ax.fill_between(times[shown], lo, hi, where=contacts[shown, i] > 0.5, color="g", alpha=0.2, step="post")
        ax.set_xlim(first, last)
        ax.set_ylabel(leg)
        if i < 5:
            ax.tick_params(labelbottom=False)
    leg_axes[-1].set_xlabel("time [s] (green: foot in contact)")
    fig.suptitle("foot heights [m] and contact phases")
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
    files["feet_plot"] = str(plot_foot_heights(times, feet[:, :, 2], contacts, out / "foot_heights.png"))

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
