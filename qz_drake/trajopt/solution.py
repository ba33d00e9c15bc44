"""The BLC's result: a verdict and trajectories as Drake PiecewisePolynomials.

A failed solve is a result too: ``success`` is False, ``reason`` says why, and the trajectories
are those of the point Ipopt returned (useful to see what went wrong).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from qz_drake.trajopt.gait import ContactSchedule

NPZ_RATE = 100.0  # [Hz]


@dataclasses.dataclass
class BlcSolution:
    """Verdict, statistics and trajectories of one BLC solve.

    Positions are of the single rigid body's origin, the CoM (``robot.com_B`` in the base link
    frame); angles are Drake's roll-pitch-yaw; forces are in newtons, world frame.
    """

    # True only if Ipopt converged and every constraint holds within violation_tolerance.
    success: bool
    # Ipopt's status text (e.g. "Success", "Local infeasibility", "Wall time exceeded").
    status: str
    # Why it failed; "" on success.
    reason: str
    # Wall time of the whole solve: building the program, Ipopt, the verdict. [s]
    solve_time: float
    # Ipopt iterations.
    iterations: int
    # Largest constraint violation at the returned point (m, rad or body weights).
    max_violation: float
    # Sizes of the program.
    num_variables: int
    num_constraints: int
    # Task duration T. [s]
    duration: float
    # CoM position and body roll-pitch-yaw, (3,)-valued. [m], [rad]
    body_position: object
    body_rpy: object
    # Per foot: position of the foot-sphere centre and ground reaction force. [m], [N]
    foot_positions: list
    foot_forces: list
    contact_schedule: ContactSchedule
    robot: object
    terrain: object
    # Friction coefficient the forces respect.
    mu: float
    # Worst violation per constraint: name -> (violation, where).
    violations: dict = dataclasses.field(default_factory=dict)
    # Wall time spent inside Ipopt (part of solve_time). [s]
    ipopt_time: float = 0.0
    # The decision vector at the returned point and the resolved parameters.
    x: np.ndarray | None = None
    params: object = None
    # The dense verdict's figures (verdict.DenseCheck; None for a non-finite point).
    dense: object = None
    # Check-and-refine re-solves it took (constraint samples added where the dense check
    # failed; solver.py).
    refinements: int = 0

    def __deepcopy__(self, memo):
        return self  # never modified after the solve; Drake copies abstract values often

    def contact(self, t) -> np.ndarray:
        """(n, L) contact flags at times t."""
        return self.contact_schedule.in_contact(t)

    def sample(self, rate: float = NPZ_RATE) -> dict[str, np.ndarray]:
        """Trajectories sampled at ``rate`` Hz from 0 to T inclusive."""
        n = int(round(self.duration * rate)) + 1
        t = np.linspace(0.0, self.duration, n)
        L = len(self.foot_positions)

        def eval_pp(pp):
            return np.array([pp.value(ti).ravel() for ti in t])

        out = {
            "t": t,
            "base_pos": eval_pp(self.body_position),
            "base_rpy": eval_pp(self.body_rpy),
            "foot_pos": np.stack([eval_pp(pp) for pp in self.foot_positions], axis=1),
            "foot_force": np.stack([eval_pp(pp) for pp in self.foot_forces], axis=1),
            "contact": self.contact(t),
        }
        assert out["foot_pos"].shape == (n, L, 3)
        return out

    def terrain_grid(self, margin: float = 1.0, resolution: float = 0.02):
        """(heights, origin, resolution) of the terrain around the motion."""
        samples = self.sample(20.0)
        pts = np.concatenate([samples["base_pos"][:, :2], samples["foot_pos"][..., :2].reshape(-1, 2)])
        lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
        return self.terrain.grid(lo[0], hi[0], lo[1], hi[1], resolution)

    def save_npz(self, path: str | Path) -> Path:
        """Writes the solution sampled at 100 Hz: t, base_pos (N, 3) (the CoM), base_rpy (N, 3),
        foot_pos (N, L, 3), foot_force (N, L, 3) [N], contact (N, L), mass, inertia (3, 3) about
        the CoM in the body frame, gravity (3,) [m/s^2], mu, the terrain (heightmap (H, W),
        origin (2,), resolution), foot_radius [m] (foot_pos are sphere centres: the sole is
        foot_radius lower), phase_durations (L, P) [s], each foot's alternating stance and
        swing durations from t = 0 (stance first), NaN-padded to the longest foot, and the
        kinematic boxes: nominal_footholds (L, 3) and box_half_sizes (L, 3) in the body frame
        about the CoM [m]."""
        path = Path(path)
        data = self.sample(NPZ_RATE)
        heights, origin, resolution = self.terrain_grid()
        durations = self.contact_schedule.phase_durations
        phases = np.full((len(durations), max(len(d) for d in durations)), np.nan)
        for leg, d in enumerate(durations):
            phases[leg, :len(d)] = d
        np.savez(path, **data, mass=float(self.robot.mass), inertia=self.robot.inertia_matrix,
                 foot_radius=float(self.robot.foot_radius), phase_durations=phases,
                 nominal_footholds=self.robot.nominal_footholds,
                 box_half_sizes=self.robot.box_half_sizes,
                 gravity=np.array([0.0, 0.0, -self.robot.gravity]), mu=float(self.mu),
                 heightmap=np.asarray(heights, dtype=float), origin=np.asarray(origin, dtype=float),
                 resolution=float(resolution))
        return path

    def summary(self) -> dict:
        """The JSON-able verdict and statistics."""
        return {"success": bool(self.success), "status": self.status, "reason": self.reason,
                "solve_time_s": round(float(self.solve_time), 4), "iterations": int(self.iterations),
                "max_violation": float(self.max_violation), "n_vars": int(self.num_variables),
                "n_constraints": int(self.num_constraints), "refinements": int(self.refinements),
                "dense": None if self.dense is None else self.dense.summary()}
