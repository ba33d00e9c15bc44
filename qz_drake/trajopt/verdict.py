"""The dense verdict: a plan checked at 100 Hz, not only at its constraint samples (issue 11;
paper 000 Eq. 1, 2, 4, 5).

Ipopt only sees the constraints at their sample times; between samples a swing foot can pass
through a riser, a stance force can pull, and the body's motion can stop matching the forces.
After Ipopt returns, the plan is therefore evaluated at every sample of a fixed rate (the rate
the .npz is saved at) on the terrain model the problem was solved on:

* swing feet: sphere centre height minus ``foot_radius`` above the terrain (Eq. 4);
* stance feet inside their kinematic boxes (Eq. 1; swing feet are reported);
* free stance footholds on supported ground (support.py: no edge or riser within the foot's
  radius plus a margin);
* every leg's thigh and shank above the ground (leg_clearance.py: the collision capsules
  sampled every 1.5 cm against the raw cells), in stance and swing;
* stance forces: normal part at least zero, inside the friction pyramid of the terrain frame at
  the foothold (Eq. 5);
* single-rigid-body residuals (Eq. 2): the linear one ``|m (r'' - g) - sum f| / (m g)`` and the
  angular one ``|I w' + w x I w - R^T sum (p - r) x f| / (m g l)`` with a reference lever
  ``l`` (``dense_residual_lever``), both at a percentile over the samples that are more than
  ``dense_switch_margin`` away from a contact switch (forces may jump there, the body's
  acceleration may not).

All quantities are the splines' exact values and derivatives (no finite differences). A plan
that violates one fails with a reason naming what and where, e.g. ``RF swing foot 0.10 m below
the terrain at t = 0.83 s``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from qz_drake.trajopt.constraints import (AngularDynamicsConstraint, ForceConstraint,
                                          KinematicsConstraint, TerrainConstraint,
                                          linear_dynamics_matrix)
from qz_drake.trajopt.formulation import first_step_end
from qz_drake.trajopt.leg_clearance import dense_link_check
from qz_drake.trajopt.legs import link_geometry
from qz_drake.trajopt.splines import LinearSamples


@dataclasses.dataclass
class DenseCheck:
    """The plan's worst figures at the dense samples and the reasons it fails (none: it passes).

    Units: metres for clearance and box excess, body weights for forces and residuals.
    """

    # Least swing-foot clearance (sphere surface above the terrain); +inf without swings. [m]
    min_swing_clearance: float
    # Largest distance of a stance foot outside its kinematic box (0 inside). [m]
    max_box_excess: float
    # The same for swing feet (reported, not failed: the issue asks for stance feet). [m]
    max_swing_box_excess: float
    # Least signed distance of a free stance foothold to unsupported ground (support.py;
    # negative: inside it); +inf without the support check. [m]
    min_support_margin: float
    # Least clearance of a leg link (capsule surface above the raw ground, leg_clearance.py);
    # +inf without the link check or without modelled legs. [m]
    min_link_clearance: float
    # Least stance normal force. [body weights]
    min_normal_force: float
    # Largest tangential force beyond the friction pyramid (0 inside). [body weights]
    max_friction_excess: float
    # Percentile (``dense_residual_percentile``) of the linear and angular residuals.
    linear_residual: float
    angular_residual: float
    # Samples checked and samples used for the residuals.
    num_samples: int
    num_residual_samples: int
    failures: list[str] = dataclasses.field(default_factory=list)
    # Where to add constraint samples so that a re-solve meets the failed checks: constraint
    # name ("kinematics", "dynamics", "linear_dynamics") -> times. [s]
    refine_times: dict = dataclasses.field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return not self.failures

    def summary(self) -> dict:
        out = {k: (float(v) if isinstance(v, (float, np.floating)) else v)
               for k, v in dataclasses.asdict(self).items() if k != "refine_times"}
        out["passed"] = self.passed
        return out


def dense_times(duration: float, rate: float) -> np.ndarray:
    """0 to duration inclusive at ``rate`` Hz: the .npz's sample times."""
    n = int(round(duration * rate)) + 1
    return np.linspace(0.0, duration, n)


def swing_sample_times(schedule, leg: int, times: np.ndarray) -> np.ndarray:
    """The times strictly inside the swings of foot ``leg`` (touchdown and liftoff are on the
    ground by construction)."""
    b = schedule.phase_boundaries(leg)
    inside = np.zeros(len(times), dtype=bool)
    for t0, t1 in zip(b[1:-1:2], b[2::2]):
        inside |= (times > t0 + 1e-9) & (times < t1 - 1e-9)
    return times[inside]


def switch_distance(schedule, times: np.ndarray) -> np.ndarray:
    """Distance of each time from the nearest contact switch of any foot. [s]"""
    switches = np.unique(np.concatenate([schedule.phase_boundaries(leg)[1:-1]
                                         for leg in range(schedule.num_legs)]))
    if not len(switches):
        return np.full(len(times), np.inf)
    return np.abs(times[:, None] - switches[None, :]).min(axis=1)


def dense_check(formulation, x: np.ndarray, rate: float | None = None) -> DenseCheck:
    """Evaluates the plan at decision vector x densely (see the module docstring)."""
    f = formulation
    v, p, robot, terrain = f.variables, f.params, f.robot, f.terrain
    rate = p.dense_check_rate if rate is None else rate
    # The samples and constraint structures depend on the schedule only: shared with the
    # earlier plans of this schedule (formulation.ScheduleParts).
    parts = f.parts
    names = robot.leg_names
    T = v.duration
    times = dense_times(T, rate)
    failures: list[str] = []
    weight = robot.weight

    # Swing clearance (Eq. 4), above the map as given (a FootScaleTerrain's ``given``).
    checked = getattr(terrain, "given", terrain)
    min_clearance, worst = np.inf, None
    for leg in range(v.num_legs):
        ts = swing_sample_times(v.schedule, leg, times)
        if not len(ts):
            continue
        c = parts.get(("dense", rate, "clearance", leg), lambda: TerrainConstraint(
            v.foot_position[leg].sample(ts, 0), checked, robot.foot_radius, 0.0, np.inf),
            terrain=checked)
        g = c.evaluate(x)
        k = int(np.argmin(g))
        if g[k] < min_clearance:
            min_clearance, worst = float(g[k]), (leg, ts[k])
    if min_clearance < -p.dense_clearance_tolerance:
        leg, t = worst
        failures.append(f"{names[leg]} swing foot {-min_clearance:.3f} m below the terrain "
                        f"at t = {t:.2f} s")

    # Kinematic boxes (Eq. 1).
    box = robot.box_half_sizes
    contact = v.schedule.in_contact(times)
    kin = parts.get(("dense", rate, "kinematics"),
                    lambda: KinematicsConstraint(v, times, robot.nominal_footholds, box))
    offset = kin.evaluate(x).reshape(len(times), v.num_legs, 3)
    # The boxes the program holds (a foot that starts outside its box keeps its room until
    # its second stance), without the solver's inset.
    lower, upper = f.box_bounds(times)
    excess = np.maximum(np.maximum(lower - offset, offset - upper), 0.0)
    max_swing_box = float((excess * ~contact[..., None]).max())
    excess = excess * contact[..., None]
    max_box = float(excess.max())
    refine: dict[str, np.ndarray] = {}
    if max_box > p.dense_box_tolerance:
        refine["kinematics"] = _worst_times(times, excess.max(axis=(1, 2)), p.dense_box_tolerance)
        k, leg, axis = np.unravel_index(int(np.argmax(excess)), excess.shape)
        failures.append(f"{names[leg]} stance foot {max_box:.3f} m outside its kinematic box "
                        f"along {'xyz'[axis]} at t = {times[k]:.2f} s")

    # Support under the free stance footholds (the start's are given, not planned).
    min_support = np.inf
    if f.support is not None:
        for leg in range(v.num_legs):
            holds = x[v.footholds[leg][1:]].reshape(-1, 3)
            if not len(holds):
                continue
            margin = f.support.margin(holds[:, 0], holds[:, 1])
            k = int(np.argmin(margin))
            if margin[k] < min_support:
                min_support = float(margin[k])
            if margin[k] < -p.dense_support_tolerance:
                t = v.schedule.stance_intervals(leg)[k + 1][0]
                relief = f.support.relief_at(holds[k, 0], holds[k, 1])
                failures.append(f"{names[leg]} stance foot on unsupported ground from t = {t:.2f} s "
                                f"(the ground within {f.support.radius:.2f} m differs by {relief:.2f} m)")

    # Legs' links above the ground (leg_clearance.py), through the stance and the swing.
    min_link = np.inf
    if p.dense_link_check:
        min_link = _link_check(f, x, times, rate, failures)

    # Stance forces (Eq. 5): normal >= 0, inside the friction pyramid.
    min_normal, max_friction = np.inf, 0.0
    worst_normal = worst_friction = None
    for leg in range(v.num_legs):
        ts = times[contact[:, leg]]
        if not len(ts):
            continue

        def force(leg=leg, ts=ts):
            stance = v.stance_of(leg, ts)
            holds = LinearSamples(np.ones((len(ts), 1, 3)), v.footholds[leg][stance][:, None, :])
            return ForceConstraint(v.foot_force[leg].sample(ts, 0), holds, terrain,
                                   p.friction_coefficient, 0.0, np.inf)
        c = parts.get(("dense", rate, "force", leg), force, terrain=terrain)
        g = c.evaluate(x).reshape(len(ts), 5)
        k = int(np.argmin(g[:, 0]))
        if g[k, 0] < min_normal:
            min_normal, worst_normal = float(g[k, 0]), (leg, ts[k])
        # Pyramid rows are (t - mu n).F <= 0: their value is the excess.
        fr = g[:, 1:].max(axis=1)
        k = int(np.argmax(fr))
        if fr[k] > max_friction:
            max_friction, worst_friction = float(fr[k]), (leg, ts[k])
    if min_normal < -p.dense_force_tolerance:
        leg, t = worst_normal
        failures.append(f"{names[leg]} stance foot pulls ({min_normal * weight:.0f} N normal "
                        f"force) at t = {t:.2f} s")
    if max_friction > p.dense_force_tolerance:
        leg, t = worst_friction
        failures.append(f"{names[leg]} stance force {max_friction * weight:.0f} N outside the "
                        f"friction pyramid at t = {t:.2f} s")

    # Single-rigid-body residuals (Eq. 2), away from contact switches.
    far = times[switch_distance(v.schedule, times) > p.dense_switch_margin]
    linear = angular = 0.0
    if len(far):
        (A, b), ang_c = parts.get(("dense", rate, "residuals"), lambda: (
            linear_dynamics_matrix(v, far, robot.gravity),
            AngularDynamicsConstraint(v, far, robot.inertia_matrix / weight)))
        lin = np.linalg.norm((A @ x - b).reshape(-1, 3), axis=1)
        ang = np.linalg.norm(ang_c.evaluate(x).reshape(-1, 3), axis=1) / p.dense_residual_lever
        q = p.dense_residual_percentile
        linear, angular = float(np.percentile(lin, q)), float(np.percentile(ang, q))
        for label, values, value, key in (("linear", lin, linear, "linear_dynamics"),
                                          ("angular", ang, angular, "dynamics")):
            if value > p.dense_residual_limit:
                refine[key] = _worst_times(far, values, p.dense_residual_limit)
                k = int(np.argmax(values))
                failures.append(
                    f"{label} single-rigid-body residual {value:.3f} body weights at the "
                    f"{q:g}th percentile (worst {values[k]:.3f} at t = {far[k]:.2f} s)")
    return DenseCheck(min_swing_clearance=min_clearance, max_box_excess=max_box,
                      max_swing_box_excess=max_swing_box, min_support_margin=min_support,
                      min_link_clearance=min_link, min_normal_force=min_normal, max_friction_excess=max_friction,
                      linear_residual=linear, angular_residual=angular, num_samples=len(times),
                      num_residual_samples=len(far), failures=failures, refine_times=refine)


def _link_check(f, x: np.ndarray, times: np.ndarray, rate: float, failures: list[str]) -> float:
    """The least link clearance of the plan at ``times``; appends a failure naming the leg,
    the link point, the time and the depth where a link dips into the ground."""
    v, robot = f.variables, f.robot
    if link_geometry(robot) is None:
        return np.inf
    com_s, rpy_s, feet_s = f.parts.get(("dense", rate, "links"), lambda: (
        v.base_position.sample(times, 0), v.base_rpy.sample(times, 0),
        [v.foot_position[leg].sample(times, 0) for leg in range(v.num_legs)]))
    feet = np.stack([s.value(x) for s in feet_s], axis=1)
    check = dense_link_check(robot, f.terrain, times, com_s.value(x), rpy_s.value(x), feet)
    # The start is given, not planned: a leg whose links start within the constraint's margin
    # of the ground (a foot on an edge, its shank at a pit's rim: measured on the raw cells,
    # whose edges are sharp, a millimetre of body motion there is a centimetre of depth) is
    # judged from its second stance on; the others, from the start.
    tolerance = f.params.dense_link_tolerance
    allowed = np.full(check.clearance.shape, -tolerance)
    near = dense_link_check(robot, f.terrain, times[:1], com_s.value(x)[:1], rpy_s.value(x)[:1],
                            feet[:1], radius=robot.link_radius + f.params.leg_clearance_margin)
    for leg in range(v.num_legs):
        if near.clearance[0, leg].min() < 0:
            allowed[times <= first_step_end(v.schedule, leg) + 1e-9, leg] = -np.inf
    excess = allowed - check.clearance
    if excess.max() > 0:
        k, leg, j = np.unravel_index(int(np.argmax(excess)), excess.shape)
        failures.append(f"{robot.leg_names[leg]} leg ({check.names[j]}) "
                        f"{-check.clearance[k, leg, j]:.3f} m into the ground at t = {times[k]:.2f} s")
    return check.min_clearance


def _worst_times(times: np.ndarray, values: np.ndarray, limit: float,
                 count: int = 12) -> np.ndarray:
    """Up to ``count`` times where values exceed limit, worst first, at least 0.02 s apart
    (neighbouring samples of one violation need one new constraint sample, not several)."""
    chosen: list[float] = []
    for k in np.argsort(-values):
        if values[k] <= limit or len(chosen) >= count:
            break
        if all(abs(times[k] - t) >= 0.02 for t in chosen):
            chosen.append(float(times[k]))
    return np.array(sorted(chosen))
