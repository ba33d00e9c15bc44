"""Phase durations as decision variables (paper 000 Eq. 3; TOWR's "optimize phase durations").

Eq. 3 makes the durations Delta T_{i,j} of every foot's phases part of the problem, with each
foot's durations summing to the task's T. The BLC's gaits move feet in swing groups, so every
foot's phase boundaries are among the schedule's *global* boundaries (the union over feet); a
global phase j of nominal length dbar_j gets a time scale rho_j = d_j / dbar_j, a decision
variable. A foot's phase is a run of global phases, so its duration is a sum of d_j and Eq. 3
holds per foot as soon as sum_j d_j = T (one linear equality). The stands at the start and at
the end keep their nominal length (rho = 1): the start velocity and the end of the task are then
fixed in time, as the task says them.

Every trajectory is written over the *nominal* time tau of its phase (each global phase of the
nominal schedule is stretched to its real length): the body nodes subdivide every global phase,
the foot and force polynomials never straddle a global boundary, and node rates are rates in
tau. A spline sampled at a fixed tau is then linear in the decision vector, whatever the
durations, and so are the constraints that read only positions and forces (kinematic boxes,
terrain, force cones on Bezier control points). Time derivatives pick up the scale: in phase j,
d/dt = (1 / rho_j) d/dtau, which is the only place the durations enter (Eq. 2's body rates and
accelerations, and the continuity of the body's velocity and acceleration across a global
boundary, where the body has one rate variable per side).

After the solve, ``PhaseLayout.realize`` turns (x, rho) into the fixed-timing plan: a
ContactSchedule with the optimised durations, and the same variables with rates divided by
their phase's scale. The dense verdict, the Drake trajectories and the .npz come from that.
"""

from __future__ import annotations

import math

import numpy as np

from qz_drake.errors import ConfigError, bad_value
from qz_drake.trajopt.gait import ContactSchedule


class PhaseLayout:
    """The global phases of a nominal schedule and the discretisation shared by the program
    with free durations and its realisation at the optimised ones.

    Args:
        schedule: the nominal ContactSchedule (its durations are dbar).
        params: BlcParameters (base_node_spacing, the force polynomial rule,
            phase_duration_bounds).
    """

    def __init__(self, schedule: ContactSchedule, params):
        self.nominal_schedule = schedule
        L = schedule.num_legs
        merged = np.concatenate([schedule.phase_boundaries(leg) for leg in range(L)])
        merged = np.sort(merged)
        keep = np.concatenate([[True], np.diff(merged) > 1e-9])
        G = merged[keep]
        G[-1] = schedule.duration
        self.nominal_boundaries = G
        self.nominal_durations = np.diff(G)
        J = len(self.nominal_durations)
        self.num_phases = J
        # Per foot: the indices of its phase boundaries among the global ones.
        self.leg_boundaries = []
        for leg in range(L):
            b = schedule.phase_boundaries(leg)
            idx = np.abs(G[None, :] - b[:, None]).argmin(axis=1)
            self.leg_boundaries.append(idx)
            for k, (a, c) in enumerate(zip(idx[1:-1:2], idx[2::2])):
                if c - a != 1:
                    raise bad_value("blc.optimize_phase_durations", True,
                                    f"needs every swing to be one phase of the schedule; swing "
                                    f"{k} of foot {leg} spans {c - a}", ConfigError)
        # Body polynomials per global phase: about base_node_spacing long in nominal time.
        spacing = params.base_node_spacing
        self.base_segments = np.array([max(1, int(math.ceil(d / spacing - 1e-9)))
                                       for d in self.nominal_durations])
        # Force polynomials per global phase (the rule of variables.py, per phase).
        most, shortest = int(params.force_polynomials_per_stance), params.min_force_polynomial_duration
        self.force_polynomials = np.array([
            most if shortest <= 0 else min(most, max(1, int(math.floor(d / shortest + 1e-9))))
            for d in self.nominal_durations])
        # Free phases: all but the stands at both ends (when there is anything between them).
        self.free = np.ones(J, dtype=bool)
        if J >= 3:
            self.free[0] = self.free[-1] = False
        lo, hi = params.phase_duration_bounds
        self.scale_lower = np.where(self.free, lo, 1.0)
        self.scale_upper = np.where(self.free, hi, 1.0)
        if J < 3:
            # Nothing to trade time with: the durations stay nominal.
            self.scale_lower[:] = self.scale_upper[:] = 1.0

    @property
    def duration(self) -> float:
        return float(self.nominal_boundaries[-1])

    def phase_of(self, tau: np.ndarray, side: str = "right") -> np.ndarray:
        """Global phase of each nominal time (closed-open; open-closed with side='left')."""
        tau = np.atleast_1d(np.asarray(tau, dtype=float))
        G = self.nominal_boundaries
        j = np.searchsorted(G, tau, side=side) - 1
        return np.clip(j, 0, self.num_phases - 1)

    def durations(self, scales: np.ndarray) -> np.ndarray:
        """Phase durations d = dbar rho, the free ones rescaled so that they sum to T exactly
        (Ipopt meets the sum only to its tolerance). [s]"""
        rho = np.clip(np.asarray(scales, dtype=float).reshape(self.num_phases),
                      self.scale_lower, self.scale_upper)
        d = self.nominal_durations * rho
        if self.free.any():
            fixed = d[~self.free].sum()
            d[self.free] *= (self.duration - fixed) / d[self.free].sum()
        return d

    def boundaries(self, durations: np.ndarray) -> np.ndarray:
        G = np.concatenate([[0.0], np.cumsum(durations)])
        G[-1] = self.duration
        return G

    def schedule(self, durations: np.ndarray) -> ContactSchedule:
        """The ContactSchedule of the given global phase durations (Eq. 3 per foot)."""
        G = self.boundaries(durations)
        phases = []
        for idx in self.leg_boundaries:
            phases.append(tuple(float(v) for v in np.diff(G[idx])))
        return ContactSchedule(tuple(phases), gait=self.nominal_schedule.gait)

    def duration_sum_row(self, num_vars: int, scale_index: np.ndarray):
        """(A, b) of sum_j dbar_j rho_j = T over the free phases (the stands are fixed)."""
        import scipy.sparse as sp

        cols = scale_index[self.free]
        A = sp.csr_matrix((self.nominal_durations[self.free], (np.zeros(len(cols), dtype=int), cols)),
                          shape=(1, num_vars))
        b = np.array([self.duration - self.nominal_durations[~self.free].sum()])
        return A, b

    def realize(self, variables, x: np.ndarray) -> np.ndarray:
        """The decision vector of the realised plan: rates in nominal time divided by their
        phase's scale (positions, forces and footholds are the same numbers)."""
        x = np.asarray(x, dtype=float).copy()
        rho = x[variables.phase_scale]
        index, phase = variables.rate_index, variables.rate_phase
        x[index] = x[index] / rho[phase]
        return x


def check_duration_bounds(bounds) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in bounds)
    except (TypeError, ValueError):
        raise bad_value("blc.phase_duration_bounds", bounds, "expected (lower, upper) ratios",
                        ConfigError) from None
    if not (0 < lo <= 1 <= hi and math.isfinite(hi)):
        raise bad_value("blc.phase_duration_bounds", bounds,
                        "expected 0 < lower <= 1 <= upper (ratios to the nominal duration)",
                        ConfigError)
    return lo, hi
