"""Independent checks of a saved BLC plan (the .npz of BlcSolution.save_npz), from its arrays
alone: no qz_drake.trajopt code, derivatives by finite differences of the 100 Hz samples.

Terrain heights come from the saved map by bilinear interpolation. The BLC solved on a smooth
interpolant of that map (a C1 bicubic for gridded maps; a quintic-smoothed step for TOWR's
closed-form terrains, saved on a 0.02 m grid), which inside a cell holding a step lies up to
0.1-0.15 x the step's rise off the bilinear one; the height tolerance is therefore 2 mm plus
0.15 x the largest kink (second difference) at the corners of the cell under the foot (2 mm on
planes, level or sloped).
"""

from __future__ import annotations

import math

import numpy as np

GRAVITY = 9.81  # [m/s^2]
# Residual limits of issue 11: 90th percentile, 0.05 body weights (angular: x 0.3 m).
RESIDUAL_PERCENTILE = 90.0
RESIDUAL_LIMIT = 0.05
RESIDUAL_LEVER = 0.3  # [m]
SWITCH_MARGIN = 0.015  # [s]


def _kinks(H):
    """Per node, the largest second difference along x or y: 0 on planes, the rise at a step."""
    K = np.zeros_like(H)
    K[:, 1:-1] = np.abs(H[:, :-2] - 2 * H[:, 1:-1] + H[:, 2:])
    K[1:-1, :] = np.maximum(K[1:-1, :], np.abs(H[:-2, :] - 2 * H[1:-1, :] + H[2:, :]))
    return K


def bilinear(data, x, y):
    """Height, gradient (hx, hy) and, per point, the largest kink at its cell's corners (how
    far the map is from a plane there: a step's rise on an edge, 0 on a plane). [m]"""
    H = data["heightmap"]
    res = float(data["resolution"])
    u = np.clip((x - data["origin"][0]) / res, 0.0, H.shape[1] - 1.0)
    v = np.clip((y - data["origin"][1]) / res, 0.0, H.shape[0] - 1.0)
    i = np.clip(np.floor(u).astype(int), 0, H.shape[1] - 2)
    j = np.clip(np.floor(v).astype(int), 0, H.shape[0] - 2)
    s, t = u - i, v - j
    h00, h10, h01, h11 = H[j, i], H[j, i + 1], H[j + 1, i], H[j + 1, i + 1]
    h = (1 - s) * (1 - t) * h00 + s * (1 - t) * h10 + (1 - s) * t * h01 + s * t * h11
    hx = ((1 - t) * (h10 - h00) + t * (h11 - h01)) / res
    hy = ((1 - s) * (h01 - h00) + s * (h11 - h10)) / res
    K = _kinks(H)
    kink = np.maximum.reduce([K[j, i], K[j, i + 1], K[j + 1, i], K[j + 1, i + 1]])
    return h, hx, hy, kink


def rotation(rpy):
    r, p, y = rpy
    Rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    Ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    Rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def body_rate(rpy, rpy_dot):
    """Body-frame angular velocity of roll-pitch-yaw rates."""
    r, p, _ = rpy
    E = np.array([[1, 0, -math.sin(p)], [0, math.cos(r), math.sin(r) * math.cos(p)],
                  [0, -math.sin(r), math.cos(r) * math.cos(p)]])
    return E @ rpy_dot


def check_plan(data) -> dict:
    """Figures of a saved plan: least swing clearance beyond its tolerance (negative: below the
    terrain), worst stance box excess [m], least stance normal force and worst friction excess
    [body weights], stance feet's distance from the ground [m], and the 90th percentiles of the
    single-rigid-body residuals away from contact switches [body weights]."""
    t, r, rpy = data["t"], data["base_pos"], data["base_rpy"]
    feet, force, contact = data["foot_pos"], data["foot_force"], data["contact"]
    radius = float(data["foot_radius"])
    m, inertia = float(data["mass"]), data["inertia"]
    weight = m * GRAVITY
    n, L, _ = feet.shape
    h, hx, hy, kink = bilinear(data, feet[..., 0], feet[..., 1])
    clearance = feet[..., 2] - radius - h
    tolerance = 2e-3 + 0.15 * kink
    swing = ~contact
    # On a step's edge (a cell with a kink over 1 mm at a corner) the saved map tells neither
    # the solved terrain's height to better than the tolerance nor its normal: stance feet are
    # checked on level cells only and counted on edges.
    level = kink < 1e-3
    on_level = contact & level
    out = {"swing_clearance": float((clearance + tolerance)[swing].min()) if swing.any() else np.inf,
           # Stance feet on the ground (0: within 2 mm).
           "stance_height_error": float(np.maximum(np.abs(clearance) - tolerance, 0.0)[on_level].max()),
           "stance_feet_on_edges": int((contact & ~level).sum())}
    # Kinematic boxes of stance feet.
    local = np.stack([(feet[k] - r[k]) @ rotation(rpy[k]) for k in range(n)]) - data["nominal_footholds"]
    excess = np.maximum(np.abs(local) - data["box_half_sizes"][None], 0.0).max(axis=-1)
    out["stance_box_excess"] = float(excess[contact].max())
    # Forces in the terrain frame at the foot.
    normal = np.stack([-hx, -hy, np.ones_like(hx)], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    t1 = np.stack([np.ones_like(hx), np.zeros_like(hx), hx], -1)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.stack([np.zeros_like(hx), np.ones_like(hx), hy], -1)
    t2 /= np.linalg.norm(t2, axis=-1, keepdims=True)
    fn = (force * normal).sum(-1)[contact & level] / weight
    f1 = np.abs((force * t1).sum(-1)[contact & level]) / weight
    f2 = np.abs((force * t2).sum(-1)[contact & level]) / weight
    mu = float(data["mu"])
    out["min_normal_force"] = float(fn.min())
    out["friction_excess"] = float(np.max(np.maximum(f1, f2) - mu * fn))
    out["swing_force"] = float(np.abs(force[swing]).max() / weight) if swing.any() else 0.0
    # Residuals by central differences, away from contact switches.
    dt = t[1] - t[0]
    changes = np.flatnonzero(np.any(contact[1:] != contact[:-1], axis=1))
    switch_times = t[changes + 1]
    lin, ang = [], []
    for k in range(2, n - 2):
        if len(switch_times) and np.abs(switch_times - t[k]).min() <= SWITCH_MARGIN:
            continue
        acc = (r[k + 1] - 2 * r[k] + r[k - 1]) / dt ** 2
        lin.append(np.linalg.norm(m * (acc - data["gravity"]) - force[k].sum(axis=0)) / weight)
        w = [body_rate(rpy[j], (rpy[j + 1] - rpy[j - 1]) / (2 * dt)) for j in (k - 1, k, k + 1)]
        w_dot = (w[2] - w[0]) / (2 * dt)
        torque = np.cross(feet[k] - r[k], force[k]).sum(axis=0)
        residual = inertia @ w_dot + np.cross(w[1], inertia @ w[1]) - rotation(rpy[k]).T @ torque
        ang.append(np.linalg.norm(residual) / (weight * RESIDUAL_LEVER))
    out["linear_residual"] = float(np.percentile(lin, RESIDUAL_PERCENTILE))
    out["angular_residual"] = float(np.percentile(ang, RESIDUAL_PERCENTILE))
    out["residual_samples"] = len(lin)
    return out


def assert_plan_holds(data, label: str = "") -> dict:
    """Asserts issue 11's figures on a saved plan; returns them."""
    f = check_plan(data)
    assert f["swing_clearance"] >= 0.0, (label, f)
    assert f["stance_height_error"] <= 1e-3, (label, f)
    assert f["stance_box_excess"] <= 3e-3, (label, f)
    assert f["min_normal_force"] >= -2e-3, (label, f)
    assert f["friction_excess"] <= 3e-3, (label, f)
    assert f["swing_force"] < 1e-6, (label, f)
    assert f["linear_residual"] <= RESIDUAL_LIMIT, (label, f)
    assert f["angular_residual"] <= RESIDUAL_LIMIT, (label, f)
    return f
