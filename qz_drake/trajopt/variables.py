"""Decision variables of the BLC and the splines they define (TOWR's phase-based
parameterisation, Winkler et al. 2018; paper 000 Eq. 3 holds by construction).

* Body: CoM position and roll-pitch-yaw angles (Drake's RollPitchYaw, R_WB = Rz Ry Rx), each a
  cubic Hermite spline with a node every ``base_node_spacing``; a node holds value and rate.
* Feet: one foothold (3 variables) per stance phase, so a stance foot cannot move; each swing is
  two cubic polynomials through a mid node. The mid node's x, y are the mean of the two footholds
  and its x, y rate 1.5 x (step / swing time), which makes the horizontal motion the smooth cubic
  with zero end velocities (TOWR's swing constraint, here eliminated rather than imposed); its
  height is a variable and its vertical rate is zero (the apex). With ``free_swing_midpoint``
  (default) the mid node's x, y and their rates get free offsets, as TOWR's swing nodes are
  free: a foot next to an edge can rise before it moves.
* Forces, in body-weight units (f / (m g)): per stance phase ``force_polynomials_per_stance``
  cubic polynomials whose nodes (value and rate) are variables, and zero during a swing. The
  force may jump at touchdown and liftoff, as a contact force can. TOWR instead pins the nodes
  next to a swing to zero (``zero_force_at_touchdown``): with a tripod's duty factor of 0.5 that
  leaves the body without support at every switch, which the 0.1 s dynamics samples do not see
  but a denser check does.

All variables live in one flat vector; blocks are named slices of it.
"""

from __future__ import annotations

import math

import numpy as np

from qz_drake.trajopt.gait import ContactSchedule
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.splines import NodeSpline


def _zero_node(times, value_idx, deriv_idx, eval_times, t) -> None:
    """Appends a force node pinned to zero at t (liftoff or touchdown: the force may jump)."""
    zero = -np.ones(3, dtype=np.int64)
    times.append(t)
    value_idx.append(zero)
    deriv_idx.append(zero)
    eval_times.append(t)


class BlcVariables:
    """Layout of the decision vector and the splines it parameterises."""

    def __init__(self, schedule: ContactSchedule, params: BlcParameters, layout=None,
                 boundaries: np.ndarray | None = None):
        """With ``layout`` (a timing.PhaseLayout), the phase-aligned layout of free phase
        durations: body nodes subdividing every global phase (``boundaries``, default the
        layout's nominal ones) with one rate per side at a global boundary, force polynomials
        per global phase, and the phase scales rho (block ``phase_scale``)."""
        self.schedule = schedule
        self.duration = T = schedule.duration
        self.num_legs = L = schedule.num_legs
        self.blocks: dict[str, slice] = {}
        self.num_vars = 0
        self.layout = layout
        # Rate variables (in nominal time with a layout) and the global phase of each.
        self._rates: list[tuple[np.ndarray, int]] = []

        if layout is None:
            num_segments = max(1, int(math.ceil(T / params.base_node_spacing - 1e-9)))
            self.base_breaks = np.linspace(0.0, T, num_segments + 1)
            num_nodes = num_segments + 1
            # (nodes, value/rate, xyz) indices.
            self.base_lin = self._allocate("base_lin", (num_nodes, 2, 3))
            self.base_ang = self._allocate("base_ang", (num_nodes, 2, 3))
            self.phase_boundaries = None
        else:
            G = layout.nominal_boundaries if boundaries is None else np.asarray(boundaries, float)
            self.phase_boundaries = G
            counts = layout.base_segments
            self.base_breaks = np.concatenate([np.linspace(G[j], G[j + 1], n + 1)
                                               for j, n in enumerate(counts)])
            node_phase = np.repeat(np.arange(len(counts)), counts + 1)
            # Node k of phase j shares its value with the last node of phase j - 1 (k = 0).
            unique = np.concatenate([np.arange(n + 1) + counts[:j].sum()
                                     for j, n in enumerate(counts)])
            self.base_lin = self._base_nodes("base_lin", unique, node_phase)
            self.base_ang = self._base_nodes("base_ang", unique, node_phase)
        self.base_position = NodeSpline.from_variables(
            self.base_breaks, self.base_lin[:, 0], self.base_lin[:, 1])
        self.base_rpy = NodeSpline.from_variables(
            self.base_breaks, self.base_ang[:, 0], self.base_ang[:, 1])

        self.footholds: list[np.ndarray] = []  # per leg (S, 3) indices
        self.apex_heights: list[np.ndarray] = []  # per leg (S - 1,) indices
        # per leg (S - 1, offset / rate, xy) indices of the free swing mid node, or None
        self.swing_midpoints: list[np.ndarray | None] = []
        self.force_nodes: list[np.ndarray] = []  # per leg (N, 2, 3) indices, -1 = zero
        self.force_node_times: list[np.ndarray] = []  # per leg (N,), nudged into the stance
        self.force_polynomial_counts: list[list[int]] = []  # per leg, per stance
        self.foot_position: list[NodeSpline] = []
        self.foot_force: list[NodeSpline] = []
        P = int(params.force_polynomials_per_stance)
        for leg in range(L):
            b = schedule.phase_boundaries(leg)
            num_stances = (len(b)) // 2
            stance = self._allocate(f"foothold_{leg}", (num_stances, 3))
            apex = self._allocate(f"apex_z_{leg}", (num_stances - 1,))
            mid = (self._allocate(f"swing_mid_{leg}", (num_stances - 1, 2, 2))
                   if params.free_swing_midpoint else None)
            self.footholds.append(stance)
            self.apex_heights.append(apex)
            self.swing_midpoints.append(mid)
            if layout is not None:
                idx = layout.leg_boundaries[leg]
                b = self.phase_boundaries[idx]
                if mid is not None:
                    for s in range(num_stances - 1):  # the swing is global phase idx[2s + 1]
                        self._rates.append((mid[s, 1].reshape(-1), int(idx[2 * s + 1])))
                self.foot_position.append(self._foot_spline(b, stance, apex, mid))
                self.foot_force.append(self._aligned_force_spline(
                    leg, idx, self.phase_boundaries, layout.force_polynomials,
                    params.zero_force_at_touchdown))
            else:
                self.foot_position.append(self._foot_spline(b, stance, apex, mid))
                self.foot_force.append(self._force_spline(
                    leg, b, P, params.zero_force_at_touchdown,
                    params.min_force_polynomial_duration))
        if layout is not None:
            self.phase_scale = self._allocate("phase_scale", (layout.num_phases,))
            self.rate_index = np.concatenate([r for r, _ in self._rates])
            self.rate_phase = np.concatenate([np.full(len(r), j) for r, j in self._rates])

    # -- layout -----------------------------------------------------------------------------
    def _allocate(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        size = int(np.prod(shape))
        self.blocks[name] = slice(self.num_vars, self.num_vars + size)
        idx = np.arange(self.num_vars, self.num_vars + size).reshape(shape)
        self.num_vars += size
        return idx

    def _base_nodes(self, name: str, unique: np.ndarray, node_phase: np.ndarray) -> np.ndarray:
        # (nodes, value/rate, xyz) indices; a node at a global boundary appears twice, with one
        # value and a rate per side.
        values = self._allocate(f"{name}_value", (int(unique.max()) + 1, 3))
        rates = self._allocate(f"{name}_rate", (len(unique), 3))
        for k, j in enumerate(node_phase):
            self._rates.append((rates[k], int(j)))
        return np.stack([values[unique], rates], axis=1)

    def _foot_spline(self, b: np.ndarray, stance: np.ndarray, apex: np.ndarray,
                     mid: np.ndarray | None = None) -> NodeSpline:
        # Nodes: stance start, stance end, swing mid, next stance start, ... (Q = 3 terms).
        # The swing mid node's x, y are the footholds' mean plus, with ``mid`` (per swing:
        # offset x, y and rate x, y variables), a free offset, and its rate 1.5 x step / swing
        # time plus a free rate: a foot can then rise before it moves forward (a block's or a
        # riser's edge next to the foothold), which the fixed smooth cubic cannot.
        times, vi, vc, di, dc = [], [], [], [], []
        num_stances = len(stance)
        one = np.ones(3)
        unused_i = np.zeros(3, dtype=np.int64)
        for s in range(num_stances):
            for t in (b[2 * s], b[2 * s + 1]):
                times.append(t)
                vi.append(np.stack([stance[s], stance[s], unused_i]))
                vc.append(np.stack([one, 0 * one, 0 * one]))
                di.append(np.zeros((3, 3), dtype=np.int64))
                dc.append(np.zeros((3, 3)))
            if s + 1 < num_stances:
                t0, t1 = b[2 * s + 1], b[2 * s + 2]
                times.append(0.5 * (t0 + t1))
                idx = np.stack([stance[s], stance[s + 1], unused_i])
                idx[:, 2] = apex[s]
                coef = np.array([[0.5, 0.5, 1.0], [0.5, 0.5, 0.0], [0.0, 0.0, 0.0]])
                didx = np.stack([stance[s], stance[s + 1], unused_i])
                rate = 1.5 / (t1 - t0)
                dcoef = np.array([[-rate, -rate, 0.0], [rate, rate, 0.0], [0.0, 0.0, 0.0]])
                if mid is not None:
                    idx[2, :2] = mid[s, 0]
                    coef[2, :2] = 1.0
                    didx[2, :2] = mid[s, 1]
                    dcoef[2, :2] = 1.0
                vi.append(idx)
                vc.append(coef)
                di.append(didx)
                dc.append(dcoef)
        return NodeSpline(np.array(times), np.array(vi), np.array(vc), np.array(di), np.array(dc))

    def _force_spline(self, leg: int, b: np.ndarray, most: int, zero_at_boundaries: bool,
                      shortest: float = 0.0) -> NodeSpline:
        # Nodes: each stance's P + 1 nodes, then a zero node at liftoff and one at touchdown
        # (repeated times: the force may jump there, as a contact force can). A stance has
        # ``most`` polynomials, fewer when they would be shorter than ``shortest`` (at least 1).
        num_stances = len(b) // 2
        times, value_idx, deriv_idx, eval_times, counts = [], [], [], [], []
        zero = -np.ones(3, dtype=np.int64)
        for s in range(num_stances):
            t0, t1 = b[2 * s], b[2 * s + 1]
            P = most if shortest <= 0 else min(most, max(1, int(np.floor((t1 - t0) / shortest + 1e-9))))
            counts.append(P)
            if s > 0:
                _zero_node(times, value_idx, deriv_idx, eval_times, t0)
            for n, t in enumerate(np.linspace(t0, t1, P + 1)):
                fixed = zero_at_boundaries and ((n == 0 and s > 0) or (n == P and s < num_stances - 1))
                if fixed:
                    value_idx.append(zero)
                    deriv_idx.append(zero)
                else:
                    node = self._allocate(f"force_{leg}_{s}_{n}", (2, 3))
                    value_idx.append(node[0])
                    deriv_idx.append(node[1])
                times.append(t)
                # Where the node's force acts: just inside its stance.
                eval_times.append(min(max(t, t0 + 1e-9), t1 - 1e-9))
            if s + 1 < num_stances:
                _zero_node(times, value_idx, deriv_idx, eval_times, t1)
        return self._force_nodes_spline(times, value_idx, deriv_idx, eval_times, counts)

    def _aligned_force_spline(self, leg: int, idx: np.ndarray, G: np.ndarray,
                              counts: np.ndarray, zero_at_boundaries: bool) -> NodeSpline:
        # As _force_spline, but a stance's polynomials are counted per global phase it spans
        # and never straddle a global boundary: there the force keeps its value (one variable)
        # and has a rate per side, each in its own phase's nominal time.
        num_stances = len(idx) // 2
        times, value_idx, deriv_idx, eval_times, per_stance = [], [], [], [], []
        zero = -np.ones(3, dtype=np.int64)
        for s in range(num_stances):
            g0, g1 = int(idx[2 * s]), int(idx[2 * s + 1])
            t0, t1 = G[g0], G[g1]
            if s > 0:
                _zero_node(times, value_idx, deriv_idx, eval_times, t0)
            shared = None
            per_stance.append(int(counts[g0:g1].sum()))
            for j in range(g0, g1):
                P = int(counts[j])
                for n, t in enumerate(np.linspace(G[j], G[j + 1], P + 1)):
                    first, last = j == g0 and n == 0, j == g1 - 1 and n == P
                    fixed = zero_at_boundaries and ((first and s > 0)
                                                    or (last and s < num_stances - 1))
                    if fixed:
                        value, rate = zero, zero
                    elif n == 0 and j > g0:
                        value = shared
                        rate = self._allocate(f"force_rate_{leg}_{s}_{j}", (3,))
                    else:
                        node = self._allocate(f"force_{leg}_{s}_{j}_{n}", (2, 3))
                        value, rate = node[0], node[1]
                    if rate[0] >= 0:
                        self._rates.append((rate, j))
                    value_idx.append(value)
                    deriv_idx.append(rate)
                    times.append(t)
                    eval_times.append(min(max(t, t0 + 1e-9), t1 - 1e-9))
                    if n == P:
                        shared = value
            if s + 1 < num_stances:
                _zero_node(times, value_idx, deriv_idx, eval_times, t1)
        return self._force_nodes_spline(times, value_idx, deriv_idx, eval_times, per_stance)

    def _force_nodes_spline(self, times, value_idx, deriv_idx, eval_times, counts) -> NodeSpline:
        nodes = np.stack([np.array(value_idx), np.array(deriv_idx)], axis=1)
        self.force_nodes.append(nodes)
        self.force_node_times.append(np.array(eval_times))
        self.force_polynomial_counts.append(counts)
        return NodeSpline.from_variables(np.array(times), nodes[:, 0], nodes[:, 1])

    # -- queries ----------------------------------------------------------------------------
    def block_indices(self, prefix: str) -> np.ndarray:
        """Indices of every block whose name starts with prefix."""
        parts = [np.arange(s.start, s.stop) for n, s in self.blocks.items() if n.startswith(prefix)]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    def force_variable_indices(self) -> np.ndarray:
        return self.block_indices("force_")

    def stance_of(self, leg: int, t: np.ndarray) -> np.ndarray:
        """Stance index of foot ``leg`` at times t (in a swing: the stance before it)."""
        b = self.schedule.phase_boundaries(leg)
        phase = np.clip(np.searchsorted(b, t, side="right") - 1, 0, len(b) - 2)
        return phase // 2
