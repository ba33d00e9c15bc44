"""A BLC solution in pictures: matplotlib plots of body, feet and forces, and a meshcat
animation (terrain, body box, feet, force arrows) recorded for a static HTML page."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydrake.geometry import Box, Cylinder, Rgba, Sphere, TriangleSurfaceMesh, SurfaceTriangle
from pydrake.math import RigidTransform, RollPitchYaw

from qz_drake.robot.params import LEG_NAMES

# Metres of arrow per newton of force.
FORCE_SCALE = 0.002
_LEG_COLORS = ("#d62728", "#ff7f0e", "#2ca02c", "#1f77b4", "#9467bd", "#8c564b")


def plot_solution(solution, path: str | Path | None = None, rate: float = 100.0):
    """Body height and pitch, feet heights with contact phases and vertical forces against
    time, and the top view of body and feet. Returns the figure (saved if path is given)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = solution.sample(rate)
    t = s["t"]
    fig, axes = plt.subplots(2, 2, figsize=(12, 7))
    ax = axes[0, 0]
    ax.plot(t, s["base_pos"][:, 2], "k", label="CoM height [m]")
    ax.plot(t, s["base_rpy"][:, 1], "k--", label="pitch [rad]")
    ax.set_xlabel("t [s]")
    ax.legend()
    ax.set_title("body")
    names = LEG_NAMES if s["foot_pos"].shape[1] == len(LEG_NAMES) else \
        [f"leg {i}" for i in range(s["foot_pos"].shape[1])]
    for ax, key, label, title in ((axes[0, 1], "foot_pos", "foot height [m]", "feet"),
                                  (axes[1, 0], "foot_force", "vertical force [N]",
                                   "vertical foot forces (0 N while a foot swings)")):
        for leg, name in enumerate(names):
            ax.plot(t, s[key][:, leg, 2], color=_LEG_COLORS[leg % 6], label=name)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
        ax.set_title(title)
    axes[0, 1].legend(ncol=3, fontsize=8)
    axes[1, 0].legend(ncol=3, fontsize=8)
    ax = axes[1, 1]
    ax.plot(s["base_pos"][:, 0], s["base_pos"][:, 1], "k", lw=2, label="CoM")
    for leg in range(s["foot_pos"].shape[1]):
        stance = s["contact"][:, leg]
        ax.plot(s["foot_pos"][stance, leg, 0], s["foot_pos"][stance, leg, 1], "o",
                color=_LEG_COLORS[leg % 6], ms=3)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("top view: CoM and stance footholds")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=100)
    return fig


def _terrain_mesh(solution, margin: float = 0.6, resolution: float = 0.05) -> TriangleSurfaceMesh:
    s = solution.sample(10.0)
    pts = np.concatenate([s["base_pos"][:, :2], s["foot_pos"][..., :2].reshape(-1, 2)])
    lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
    xs = np.arange(lo[0], hi[0] + resolution, resolution)
    ys = np.arange(lo[1], hi[1] + resolution, resolution)
    X, Y = np.meshgrid(xs, ys)
    Z = solution.terrain.height(X, Y)
    vertices = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    W = len(xs)
    triangles = []
    for j in range(len(ys) - 1):
        for i in range(W - 1):
            a, b, c, d = j * W + i, j * W + i + 1, (j + 1) * W + i, (j + 1) * W + i + 1
            triangles += [SurfaceTriangle(a, b, d), SurfaceTriangle(a, d, c)]
    return TriangleSurfaceMesh(triangles, vertices)


def animate_solution(meshcat, solution, *, rate: float = 30.0, prefix: str = "blc",
                     body_size=(0.9, 0.6, 0.15)) -> None:
    """Records the solution in meshcat: terrain, the body as a box, feet as spheres (red in
    swing, grey in stance) and ground reaction forces as arrows of FORCE_SCALE m/N. Call
    ``meshcat.PublishRecording()`` afterwards (done here) and save ``meshcat.StaticHtml()``."""
    meshcat.SetObject(f"{prefix}/terrain", _terrain_mesh(solution), Rgba(0.65, 0.6, 0.5, 1.0))
    meshcat.SetObject(f"{prefix}/body", Box(*body_size), Rgba(0.2, 0.4, 0.8, 0.8))
    num_legs = len(solution.foot_positions)
    for leg in range(num_legs):
        meshcat.SetObject(f"{prefix}/foot{leg}", Sphere(solution.robot.foot_radius),
                          Rgba(0.2, 0.2, 0.2, 1.0))
        # A unit-length arrow shaft along +z, starting at its origin; scaled per frame.
        meshcat.SetObject(f"{prefix}/force{leg}/shaft", Cylinder(0.012, 1.0), Rgba(0.9, 0.1, 0.1, 1.0))
        meshcat.SetTransform(f"{prefix}/force{leg}/shaft", RigidTransform([0.0, 0.0, 0.5]))
    s = solution.sample(rate)
    meshcat.StartRecording(frames_per_second=rate, set_visualizations_while_recording=False)
    animation = meshcat.get_mutable_recording()
    for k in range(len(s["t"])):
        X_WB = RigidTransform(RollPitchYaw(s["base_rpy"][k]), s["base_pos"][k])
        animation.SetTransform(k, f"/drake/{prefix}/body", X_WB)
        for leg in range(num_legs):
            p = s["foot_pos"][k, leg]
            animation.SetTransform(k, f"/drake/{prefix}/foot{leg}", RigidTransform(p))
            f = s["foot_force"][k, leg]
            norm = float(np.linalg.norm(f))
            # The arrow's z axis along the force, its length by the "scale" property.
            z = f / norm if norm > 1e-6 else np.array([0.0, 0.0, 1.0])
            R = _rotation_with_z(z)
            animation.SetTransform(k, f"/drake/{prefix}/force{leg}", RigidTransform(R, p))
            animation.SetProperty(k, f"/drake/{prefix}/force{leg}", "scale",
                                  [1.0, 1.0, max(FORCE_SCALE * norm, 1e-4)])
    meshcat.StopRecording()
    meshcat.PublishRecording()


def _rotation_with_z(z: np.ndarray):
    from pydrake.math import RotationMatrix

    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.9 else np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return RotationMatrix(np.column_stack([x, np.cross(z, x), z]))
