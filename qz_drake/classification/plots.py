"""Figures of paper 002 (headless matplotlib, PNG): the impedance sweep (Fig. 13), confusion
matrices (Table 1), vibration box plots (Figs. 15-16) and per-leg labels on a mixed floor."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from qz_drake.robot.params import LEG_NAMES  # noqa: E402


def plot_impedance_sweep(result: dict, path) -> Path:
    """One column per stiffness: hip height against its sine target, and the error."""
    runs = result["runs"]
    fig, axes = plt.subplots(2, len(runs), figsize=(4.2 * len(runs), 5.5), sharex=True, squeeze=False)
    for j, (run, k) in enumerate(zip(runs, result["stiffness_N_per_m"])):
        top, bottom = axes[0, j], axes[1, j]
        top.plot(run["times"], run["desired"], "k--", lw=1, label="target")
        top.plot(run["times"], run["hip"], "C0", lw=1.2, label="hip")
        top.set_title(f"K = {k / 1e3:.0f} kN/m" + (" (oscillates)" if result["oscillates"][j] else ""))
        top.set_ylabel("hip height [m]")
        top.legend(loc="upper right", fontsize=8)
        bottom.plot(run["times"], run["error"], "C3", lw=1.2)
        bottom.axhline(0.0, color="k", lw=0.5)
        bottom.set_ylabel("position error [m]")
        bottom.set_xlabel("time [s]")
        bottom.text(0.02, 0.05, f"max |error| {result['max_error_m'][j]:.3f} m", transform=bottom.transAxes)
    fig.suptitle("Leg impedance on 70 kN/m ground (paper 002, Fig. 13)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_confusion_matrices(report: dict, path) -> Path:
    """Per-leg confusion matrices (rows actual, columns predicted) with counts."""
    classes = report["classes"]
    legs = report["per_leg"]
    cols = min(3, len(legs))
    rows = int(np.ceil(len(legs) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.ravel()[len(legs):]:
        ax.axis("off")
    for ax, leg in zip(axes.ravel(), legs):
        c = np.asarray(leg["confusion"])
        ax.imshow(c, cmap="Blues")
        for (i, j), n in np.ndenumerate(c):
            ax.text(j, i, str(n), ha="center", va="center", color="white" if n > c.max() / 2 else "black")
        ax.set_xticks(range(len(classes)), classes, fontsize=8)
        ax.set_yticks(range(len(classes)), classes, fontsize=8)
        ax.set_xlabel("predicted")
        ax.set_ylabel("actual")
        ax.set_title(f"{leg['leg']}: {100 * leg['accuracy']:.2f} %")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_vibration_boxes(runs: dict, path, *, quantity: str = "vertical_acceleration",
                         unit: str = "m/s^2") -> Path:
    """Figs. 15-16: for each case (e.g. "foam, 0.6 m/s"), box plots of a body signal with the
    fixed default stiffness and with adaptive stiffness, next to its time trace."""
    cases = list(runs)
    fig, axes = plt.subplots(len(cases), 2, figsize=(11, 3.4 * len(cases)), squeeze=False,
                             gridspec_kw={"width_ratios": [2.4, 1.3]})
    for row, case in zip(axes, cases):
        trace, box = row
        data = []
        for k, (label, run) in enumerate(runs[case].items()):
            trace.plot(run["times"], run[quantity], lw=0.8, color=f"C{k}", label=label)
            data.append(run[quantity][run["judged"]])
        trace.set_title(case)
        trace.set_xlabel("time [s]")
        trace.set_ylabel(f"{quantity.replace('_', ' ')} [{unit}]")
        trace.legend(fontsize=8)
        # One variant a line under its box: "adaptive (paper presets)" -> "adaptive\n(paper presets)".
        box.boxplot(data, tick_labels=[label.replace(" (", "\n(") for label in runs[case]])
        box.tick_params(axis="x", labelsize=7)
        box.set_title("judged window")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_label_timeline(times, labels, truth, classes, path, *, stance_times=None) -> Path:
    """Per leg, the classifier's label and the material under the foot over time."""
    fig, axes = plt.subplots(len(LEG_NAMES), 1, figsize=(9, 1.3 * len(LEG_NAMES)), sharex=True)
    for leg, ax in enumerate(axes):
        ax.step(times, truth[:, leg], where="post", color="k", lw=2.5, alpha=0.35, label="under the foot")
        ax.step(times, labels[:, leg], where="post", color="C1", lw=1.2, label="classifier")
        ax.set_yticks(range(-1, len(classes)), ["none", *classes], fontsize=7)
        ax.set_ylabel(LEG_NAMES[leg])
    axes[0].legend(loc="upper left", fontsize=7, ncol=2)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
