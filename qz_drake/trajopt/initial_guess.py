"""Initial guesses for the BLC: a straight line over the terrain, or a previous solution
shifted in time (a warm start when the BLC replans).

Straight line (TOWR's initialisation, made terrain-aware): the body moves from the start to the
target along a smooth cubic (zero velocity at both ends); at every node its height and its roll
and pitch follow a plane fitted to the terrain under the nominal footholds; each stance foothold
is the nominal foothold of the body pose at the middle of that stance, dropped onto the terrain;
swing apexes are ``swing_apex_height`` above the higher of the two footholds; and the weight is
shared equally by the feet in stance, pushing straight up.
"""

from __future__ import annotations

import numpy as np

from qz_drake.trajopt.splines import swing_profile


def _yaw_matrix(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((len(yaw), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def terrain_fitted_pose(robot, terrain, xy: np.ndarray, yaw: np.ndarray):
    """Height, roll and pitch (each (n,)) of a body at xy (n, 2) and yaw (n,) standing on the
    plane through the terrain under its nominal footholds; feet over a hole or a block (more
    than ``OUTLIER`` off the first fit) are left out of a second fit."""
    feet_B = robot.nominal_footholds
    R = _yaw_matrix(yaw)
    feet_W = xy[:, None, :] + np.einsum("nij,lj->nli", R[:, :2, :2], feet_B[:, :2])
    heights = terrain.height(feet_W[..., 0], feet_W[..., 1])  # (n, L)
    # Fit h = a + b u + c v in the yawed frame (u forward, v left).
    design = np.column_stack([np.ones(len(feet_B)), feet_B[:, :2]])
    coef, *_ = np.linalg.lstsq(design, heights.T, rcond=None)  # (3, n)
    residual = np.abs(heights - (design @ coef).T)
    for k in np.flatnonzero(residual.max(axis=1) > OUTLIER):
        keep = residual[k] <= np.sort(residual[k])[len(feet_B) // 2]  # the better half
        if keep.sum() >= 3:
            coef[:, k] = np.linalg.lstsq(design[keep], heights[k, keep], rcond=None)[0]
    a, b, c = coef
    pitch = -np.arctan(b)
    roll = np.arctan(c * np.cos(pitch))
    # The CoM sits nominal_height above the plane (vertically: the box takes up the rest).
    z = a + robot.nominal_height
    return z, roll, pitch


# A foot more than this above or below the fitted plane is over a hole or a block. [m]
OUTLIER = 0.08
# Added to the score of a final stance foothold's candidate that lies outside the box at the
# target and whose nearest point inside that box is unsupported ground (the other terms: about
# 0.1-0.3 for ground off the body's plane, 0.3 per metre outside a box).
UNREPAIRABLE_PENALTY = 1.0


def choose_foothold(robot, terrain, leg: int, body_xy: np.ndarray, body_yaw: float,
                    plane_z: float) -> np.ndarray:
    """A foothold for the guess: among points of the kinematic box's footprint around the
    nominal foothold, the one whose height is nearest the body's terrain plane, on level
    ground, nearest the nominal (a crude foothold planner: keeps the guess out of gaps and off
    edges)."""
    box = robot.box_half_sizes[leg]
    du = np.linspace(-0.7 * box[0], 0.7 * box[0], 9)
    dv = np.linspace(-0.5 * box[1], 0.5 * box[1], 3)
    U, V = np.meshgrid(du, dv)
    c, s = np.cos(body_yaw), np.sin(body_yaw)
    nominal = robot.nominal_footholds[leg, :2]
    pu, pv = nominal[0] + U.ravel(), nominal[1] + V.ravel()
    x = body_xy[0] + c * pu - s * pv
    y = body_xy[1] + s * pu + c * pv
    h, hx, hy, *_ = terrain.height_derivatives(x, y)
    score = (np.abs(h - plane_z) + 0.05 * np.hypot(hx, hy)
             + 0.1 * np.hypot(U.ravel() / box[0], V.ravel() / box[1]))
    k = int(np.argmin(score))
    return np.array([x[k], y[k], h[k] + robot.foot_radius])


# Added to the score of a candidate whose leg's links would sink below the clearance field at
# the stance's start or end (the body level at its nominal height over the candidate, at the
# guess's position and heading there), plus LINK_PENALTY_PER_METRE times the depth: a foothold back from a riser where the knee-out shank would lean on its nose
# (issue 34) outscores one at the riser's foot. Larger than the other terms: a leg on the
# terrain is a failed walk.
LINK_PENALTY = 0.5
LINK_PENALTY_PER_METRE = 5.0


def choose_stance_foothold(robot, terrain, leg: int, body_xy: np.ndarray, body_yaw: np.ndarray,
                           plane_z: float, previous_z: float = -np.inf,
                           final: bool = False, support=None, links=None) -> np.ndarray:
    """A foothold for the guess that the foot can keep through its whole stance: body poses
    at the stance's start and end (``body_xy`` (2, 2), ``body_yaw`` (2,)); candidates over the
    union of the two kinematic boxes' footprints, scored by how far the ground around them
    (the point and four points a foot diameter away) is from the body's terrain plane, then by
    how far they leave either box, then by their distance from the nominal foothold at
    mid-stance. Unlike ``choose_foothold`` (the box around mid-stance only) it looks past a
    gap or an edge that fills that box, which the optimiser cannot cross (the foothold's
    height constraint pulls it into the gap).

    ``final``: the stance ends the task, with the body's x, y and yaw at the target (the second
    pose), so a foothold outside the box there must move into it, which the body cannot do for
    it. With ``support`` (a SupportField), a candidate outside that box whose nearest point in
    it is unsupported gets UNREPAIRABLE_PENALTY (issue 11: on the 0.20 m Fig. 5 stairs the
    level first stair 13 mm outside the front foot's final box outscored the second stair
    inside it; the box's edge there is the riser's unsupported strip, and Ipopt ran out of
    time). A candidate a move away from supported ground in the box keeps its score: the body
    tilts and the foot moves a little (scoring every metre outside that box, 10 a metre, lost
    three of 189 capability trials that the guess had solved).

    ``links``: (clearance, body position (2, 3), body rpy (2, 3)) with ``clearance`` a
    leg_clearance.LinkClearance; a candidate whose leg's links would be below the clearance
    field at either pose gets LINK_PENALTY plus LINK_PENALTY_PER_METRE per metre of depth."""
    box = robot.box_half_sizes[leg]
    nominal = robot.nominal_footholds[leg, :2]
    c, s = np.cos(body_yaw), np.sin(body_yaw)
    corners = []
    for k in range(2):
        for du in (-box[0], box[0]):
            for dv in (-box[1], box[1]):
                u, w = nominal[0] + du, nominal[1] + dv
                corners.append((body_xy[k, 0] + c[k] * u - s[k] * w,
                                body_xy[k, 1] + s[k] * u + c[k] * w))
    corners = np.array(corners)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    X, Y = np.meshgrid(np.linspace(lo[0], hi[0], 25), np.linspace(lo[1], hi[1], 9))
    x, y = X.ravel(), Y.ravel()
    r = 2 * robot.foot_radius + 0.01
    # The body's plane sags over a hole that most feet straddle: the reference is the highest
    # of it, the upper quartile of the ground in the window and the foot's previous foothold
    # (sole height); the quartile no higher than the box reaches above the plane, or a wall or
    # a tall box in the window would make its top the ground to stand on.
    quartile = min(float(np.percentile(terrain.height(x, y), 75)), plane_z + float(box[2]))
    plane_z = max(plane_z, quartile, previous_z)
    rough = np.zeros_like(x)
    for dx, dy in ((0, 0), (r, 0), (-r, 0), (0, r), (0, -r)):
        rough = np.maximum(rough, np.abs(terrain.height(x + dx, y + dy) - plane_z))
    # Per pose: the candidates in its body frame, from the nominal foothold, and their distance
    # outside its box.
    frames, outside = [], []
    for k in range(2):
        dx, dy = x - body_xy[k, 0], y - body_xy[k, 1]
        u = c[k] * dx + s[k] * dy - nominal[0]
        w = -s[k] * dx + c[k] * dy - nominal[1]
        frames.append((u, w))
        outside.append(np.hypot(np.maximum(np.abs(u) - box[0], 0), np.maximum(np.abs(w) - box[1], 0)))
    excess = np.maximum(outside[0], outside[1])
    mid = body_xy.mean(axis=0)
    cm, sm = np.cos(body_yaw.mean()), np.sin(body_yaw.mean())
    target = mid + np.array([cm * nominal[0] - sm * nominal[1], sm * nominal[0] + cm * nominal[1]])
    score = rough + 0.3 * excess + 0.05 * np.hypot(x - target[0], y - target[1])
    if final and support is not None and np.any(outside[1] > 0):
        # The nearest point of the box at the target (the second pose).
        u, w = frames[1]
        du = np.clip(u, -box[0], box[0]) - u
        dw = np.clip(w, -box[1], box[1]) - w
        near_x = x + c[1] * du - s[1] * dw
        near_y = y + s[1] * du + c[1] * dw
        score = score + UNREPAIRABLE_PENALTY * ((outside[1] > 0) & (support.margin(near_x, near_y) < 0))
    if links is not None:
        clearance, body_pos, body_rpy = links
        # Judged where the foothold will be: an unsupported candidate is moved to the nearest
        # supported cell afterwards (straight_line_guess), e.g. from a riser to the step below
        # it, where the shank leans on the nose.
        xy = np.column_stack([x, y]) if support is None else support.nearest_supported(x, y)
        feet = np.column_stack([xy, terrain.height(xy[:, 0], xy[:, 1]) + robot.foot_radius])
        # The leg's shape as the body will hold it over this foothold: level, at its nominal
        # height above it (the guess's body sags into gaps and holes, and any leg over one
        # would look buried; a gap then drew the feet into it).
        depth = np.zeros(len(x))
        for k in range(2):
            com = np.column_stack([np.broadcast_to(body_pos[k, :2], (len(x), 2)),
                                   feet[:, 2] - robot.nominal_footholds[leg, 2]])
            depth = np.maximum(depth, clearance.depth(leg, com, [0.0, 0.0, body_rpy[k, 2]], feet))
        score = score + (depth > 0) * (LINK_PENALTY + LINK_PENALTY_PER_METRE * depth)
    k = int(np.argmin(score))
    return np.array([x[k], y[k], terrain.height(x[k], y[k]) + robot.foot_radius])


def straight_line_body(formulation) -> tuple[np.ndarray, np.ndarray]:
    """The straight-line body at the base nodes: positions (n, 3) and roll, pitch, yaw (n, 3)."""
    f = formulation
    v = f.variables
    start, target = f.start_position, f.target
    s, _, _ = swing_profile(v.base_breaks / v.duration)
    xy = start[:2] + s[:, None] * (target[:2] - start[:2])
    yaw = f.start_rpy[2] + s * (f.target_yaw - f.start_rpy[2])
    z, roll, pitch = terrain_fitted_pose(f.robot, f.terrain, xy, yaw)
    return np.column_stack([xy, z]), np.column_stack([roll, pitch, yaw])


def foothold_guess(formulation) -> str:
    """The foothold guess a formulation's straight-line guess uses, "mid" or "stance":
    ``params.foothold_guess``, where "auto" is "stance" when the body travels at least the
    shortest half length of the kinematic boxes and "mid" for a turn in place."""
    f = formulation
    choice = f.params.foothold_guess
    if choice != "auto":
        return choice
    travel = float(np.hypot(*(f.target[:2] - f.start_position[:2])))
    return "stance" if travel >= float(f.robot.box_half_sizes[:, 0].min()) else "mid"


def straight_line_guess(formulation) -> np.ndarray:
    """The straight-line initial guess x0 for a formulation."""
    f = formulation
    v, robot, terrain, params = f.variables, f.robot, f.terrain, f.params
    T = v.duration
    x0 = np.zeros(v.num_vars)
    start, target = f.start_position, f.target
    breaks = v.base_breaks
    _, ds, _ = swing_profile(breaks / T)
    pos, rpy = straight_line_body(f)
    z, roll, pitch, yaw = pos[:, 2], rpy[:, 0], rpy[:, 1], rpy[:, 2]
    # Node rates: exact for the cubic in x, y, yaw; differences for the fitted z, roll, pitch
    # (over distinct node times: with free phase durations a node at a phase boundary is
    # there twice, once per side).
    distinct, first, node = np.unique(breaks, return_index=True, return_inverse=True)

    def gradient(values):
        if len(distinct) == len(breaks):
            return np.gradient(values, breaks)
        return np.gradient(values[first], distinct)[node]

    pos_rate = np.column_stack([np.outer(ds / T, target[:2] - start[:2]), gradient(z)])
    rpy_rate = np.column_stack([gradient(roll), gradient(pitch),
                                ds / T * (f.target_yaw - f.start_rpy[2])])
    x0[v.base_lin[:, 0]] = pos
    x0[v.base_lin[:, 1]] = pos_rate
    x0[v.base_ang[:, 0]] = rpy
    x0[v.base_ang[:, 1]] = rpy_rate

    def body_at(t):
        t = np.atleast_1d(t)
        return (np.column_stack([np.interp(t, breaks, pos[:, i]) for i in range(3)]),
                np.interp(t, breaks, yaw))

    schedule = v.schedule
    feet_z = robot.nominal_footholds[:, 2] - robot.foot_radius  # sole below the CoM
    window = foothold_guess(f) == "stance"
    links = f.link_clearance() if window else None

    def pose_at(t):
        t = np.atleast_1d(t)
        return (np.column_stack([np.interp(t, breaks, pos[:, i]) for i in range(3)]),
                np.column_stack([np.interp(t, breaks, rpy[:, i]) for i in range(3)]))
    for leg in range(v.num_legs):
        stances = schedule.stance_intervals(leg)
        mids = np.array([0.5 * (a + b) for a, b in stances])
        body, body_yaw = body_at(mids)
        if window:
            ends, end_yaw = body_at(np.array(stances).reshape(-1))
            footholds = [f.start_feet[leg]]
            end_pos, end_rpy = pose_at(np.array(stances).reshape(-1))
            for k in range(1, len(mids)):
                footholds.append(choose_stance_foothold(
                    robot, terrain, leg, ends[2 * k:2 * k + 2, :2], end_yaw[2 * k:2 * k + 2],
                    body[k, 2] + feet_z[leg], footholds[-1][2] - robot.foot_radius,
                    final=stances[k][1] >= T - 1e-9, support=f.support,
                    links=None if links is None else
                    (links, end_pos[2 * k:2 * k + 2], end_rpy[2 * k:2 * k + 2])))
            footholds = np.array(footholds)
        else:
            footholds = np.array([
                choose_foothold(robot, terrain, leg, body[k, :2], body_yaw[k],
                                body[k, 2] + feet_z[leg])
                for k in range(len(mids))])
        if f.support is not None and len(footholds) > 1:
            # Off unsupported ground: to the nearest supported cell, on the terrain there.
            moved = f.support.unsupported_at(footholds[1:, 0], footholds[1:, 1])
            if moved.any():
                xy = f.support.nearest_supported(footholds[1:, 0], footholds[1:, 1])[moved]
                footholds[1:][moved] = np.column_stack(
                    [xy, terrain.height(xy[:, 0], xy[:, 1]) + robot.foot_radius])
        if f.terminal is not None and f.terminal.fixed[leg]:
            footholds[-1] = f.terminal.feet[leg]
        x0[v.footholds[leg]] = footholds
        if len(stances) > 1:
            mid = 0.5 * (footholds[:-1] + footholds[1:])
            ground = np.maximum.reduce([footholds[:-1, 2], footholds[1:, 2],
                                        terrain.height(mid[:, 0], mid[:, 1]) + robot.foot_radius])
            x0[v.apex_heights[leg]] = ground + 1.5 * params.swing_apex_height
    f.fix_start(x0)
    _share_weight(f, x0)
    if v.layout is not None:
        x0[v.phase_scale] = 1.0  # the nominal durations
    return x0


def _share_weight(f, x0: np.ndarray) -> None:
    """Vertical forces at every free force node: the weight shared by the feet in stance."""
    v = f.variables
    schedule = v.schedule
    for leg in range(v.num_legs):
        nodes = v.force_nodes[leg]
        free = nodes[:, 0, 0] >= 0
        t = v.force_node_times[leg][free]
        count = np.maximum(schedule.in_contact(t).sum(axis=1), 1)
        x0[nodes[free, 0, 2]] = 1.0 / count
        x0[nodes[free, 0, :2]] = 0.0
        x0[nodes[free, 1]] = 0.0


def shifted_solution_guess(formulation, solution, time_shift: float = 0.0) -> np.ndarray:
    """An initial guess from a previous BlcSolution sampled at t + time_shift (clamped to its
    duration): body nodes, footholds at mid-stance, apexes and forces. Quantities the previous
    solution cannot provide (a foot's swing where it stood) fall back to the straight line."""
    f = formulation
    v = f.variables
    x0 = straight_line_guess(f)
    end = solution.duration

    def at(t):
        return np.clip(np.asarray(t, dtype=float) + time_shift, 0.0, end)

    for pp, idx in ((solution.body_position, v.base_lin), (solution.body_rpy, v.base_ang)):
        t = at(v.base_breaks)
        x0[idx[:, 0]] = np.array([pp.value(ti).ravel() for ti in t])
        x0[idx[:, 1]] = np.array([pp.EvalDerivative(ti, 1).ravel() for ti in t])
    weight = f.robot.weight
    if solution.robot.num_legs == v.num_legs:
        for leg in range(v.num_legs):
            stances = v.schedule.stance_intervals(leg)
            mids = at([0.5 * (a + b) for a, b in stances])
            feet = np.array([solution.foot_positions[leg].value(t).ravel() for t in mids])
            x0[v.footholds[leg]] = feet
            swings = v.schedule.swing_intervals(leg)
            if len(swings):
                mids = at([0.5 * (a + b) for a, b in swings])
                x0[v.apex_heights[leg]] = [solution.foot_positions[leg].value(t)[2, 0] for t in mids]
            nodes = v.force_nodes[leg]
            free = nodes[:, 0, 0] >= 0
            times = at(v.force_node_times[leg][free])
            pp = solution.foot_forces[leg]
            x0[nodes[free, 0]] = np.array([pp.value(t).ravel() for t in times]) / weight
            x0[nodes[free, 1]] = np.array([pp.EvalDerivative(t, 1).ravel() for t in times]) / weight
    f.put_terminal_feet(x0)
    f.fix_start(x0)
    return x0
