"""One strict success verdict for walks: scenario files and capability trials alike.

A walk succeeds only if every check passes; each failed check is a reason with a code, so a
label in the capability dataset says *why* a trial failed (paper 000 II-E.1 learns the
success of BLC missions executed by the robot, not of plans):

``blc_infeasible``  the BLC found no trajectory for a mission (infeasible or not converged);
``blc_time_limit``  the BLC ran out of its time limit (paper 000 III-A: 5 s);
``fell``            the trunk tilted past ``max_tilt_deg``;
``trunk_contact``   the trunk touched the terrain;
``leg_contact``     a thigh or shank touched the terrain (paper 000 Fig. 2), or two legs met;
``tracking``        a joint left its reference by more than ``max_joint_error_deg`` at some
                    instant (a spike fails even if the RMS is small);
``slip``            a foot slid more than ``max_foot_slip_m`` during one contact;
``missed_target``   the final base position or heading is off the target, or the walk ran
                    out of time.

Codes are listed in the order a reason is reported first: a BLC failure explains what
follows it, a fall explains contacts.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from qz_drake.state_layout import BASE_XY, JOINT_Q, base_rpy, tilt_deg

REASON_CODES: tuple[str, ...] = ("blc_infeasible", "blc_time_limit", "fell", "trunk_contact",
                                 "leg_contact", "tracking", "slip", "missed_target")


@dataclasses.dataclass
class Verdict:
    """The outcome of a walk: success, the failed checks' codes in REASON_CODES order, and one
    message per failed check."""

    success: bool
    reasons: list[str]
    messages: list[str]
    measures: dict

    @property
    def reason(self) -> str:
        """The first reason's code ('' on success)."""
        return self.reasons[0] if self.reasons else ""

    @property
    def message(self) -> str:
        return "; ".join(self.messages)


def blc_failure_code(reason: str) -> str:
    """blc_time_limit when the solver ran out of its budget (time or iterations, see
    qz_drake.capability.trials.TrialConfig), else blc_infeasible."""
    text = reason.lower()
    return "blc_time_limit" if ("time limit" in text or "wall time exceeded" in text
                                or "cpu time exceeded" in text or "iteration" in text) else "blc_infeasible"


def foot_slip(feet_W: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """Largest horizontal drift of each foot during one continuous contact, (6,). [m]

    feet_W (N, 6, 3) foot positions, contacts (N, 6) 1 when in contact.
    """
    in_contact = contacts > 0.5
    worst = np.zeros(feet_W.shape[1])
    for leg in range(feet_W.shape[1]):
        c = in_contact[:, leg]
        if not c.any():
            continue
        # Label each contact interval; drift from the interval's first sample.
        starts = c & ~np.concatenate([[False], c[:-1]])
        interval = np.cumsum(starts) * c
        first = np.flatnonzero(starts)
        anchor = feet_W[first[interval[c] - 1], leg, :2]
        worst[leg] = float(np.max(np.linalg.norm(feet_W[c, leg, :2] - anchor, axis=1)))
    return worst


def judge_walk(criteria, *, goal_xy_yaw, times, states, desired_q, feet_W, contacts, trunk,
               leg_link_force, self_force, blc_failures=(), fell: bool = False,
               timed_out: bool = False) -> Verdict:
    """Judges a walk from its logs (all sampled at the same times).

    Args:
        criteria: SuccessCriteria (qz_drake.config) with the bounds.
        goal_xy_yaw: the final target (x, y, yaw) of the base; yaw None: any heading. [m, rad]
        times: (N,) sample times; states (N, 49) station states; desired_q (N, 18) the joint
            references; feet_W (N, 6, 3) foot positions; contacts (N, 6) foot contact flags;
            trunk (N,) trunk contact flags; leg_link_force (N, 6) terrain force on each leg's
            links [N]; self_force (N,) largest force between two legs [N].
        blc_failures: the BLC's reasons for each mission it could not solve.
        fell: the run stopped early because the robot fell.
        timed_out: the run ended before the last mission did.
    """
    codes: dict[str, str] = {}

    def fail(code: str, message: str) -> None:
        codes.setdefault(code, message)

    for reason in blc_failures:
        fail(blc_failure_code(reason), f"BLC: {reason}")
    tilts = np.array([tilt_deg(x) for x in states]) if len(states) else np.zeros(1)
    max_tilt = float(tilts.max())
    if fell or max_tilt > criteria.max_tilt_deg:
        fail("fell", f"tilt {max_tilt:.0f} deg > {criteria.max_tilt_deg:g} deg")
    trunk_contacts = int(np.count_nonzero(np.asarray(trunk) > 0.5))
    if trunk_contacts:
        fail("trunk_contact", f"trunk touched the terrain ({trunk_contacts} samples)")
    leg_force = np.asarray(leg_link_force, dtype=float).reshape(len(times), -1)
    leg_samples = leg_force > criteria.leg_contact_force
    worst_leg_force = float(leg_force.max()) if leg_force.size else 0.0
    if leg_samples.any():
        legs = sorted(set(np.nonzero(leg_samples)[1].tolist()))
        from qz_drake.robot.params import LEG_NAMES
        fail("leg_contact", f"{', '.join(LEG_NAMES[i] for i in legs)} leg link on the terrain "
                            f"(worst {worst_leg_force:.0f} N)")
    self_force = np.asarray(self_force, dtype=float).reshape(-1)
    worst_self = float(self_force.max()) if self_force.size else 0.0
    if worst_self > criteria.leg_contact_force:
        fail("leg_contact", f"two legs collided ({worst_self:.0f} N)")
    if len(states):
        error = np.abs(states[:, JOINT_Q] - desired_q[:, :18])
        k, j = np.unravel_index(int(np.argmax(error)), error.shape)
        max_joint_error = float(np.degrees(error[k, j]))
    else:
        max_joint_error, k, j = 0.0, 0, 0
    if max_joint_error > criteria.max_joint_error_deg:
        fail("tracking", f"joint {j} off its reference by {max_joint_error:.0f} deg at "
                         f"t = {times[k]:.2f} s")
    slip = foot_slip(feet_W, contacts) if len(states) else np.zeros(6)
    if slip.max() > criteria.max_foot_slip_m:
        fail("slip", f"leg {int(np.argmax(slip))} slid {slip.max():.3f} m in one contact")
    final_xy_error = math.inf
    final_yaw_error = math.inf
    if len(states):
        final_xy_error = float(np.hypot(*(states[-1, BASE_XY] - np.asarray(goal_xy_yaw[:2], dtype=float))))
        if goal_xy_yaw[2] is None:
            final_yaw_error = 0.0
        else:
            dyaw = base_rpy(states[-1])[2] - goal_xy_yaw[2]
            final_yaw_error = float(abs(np.degrees(math.atan2(math.sin(dyaw), math.cos(dyaw)))))
    if final_xy_error > criteria.max_final_xy_error:
        fail("missed_target", f"final base {final_xy_error:.2f} m from the target")
    if final_yaw_error > criteria.max_final_yaw_error_deg:
        fail("missed_target", f"final heading {final_yaw_error:.0f} deg off the target")
    if timed_out:
        fail("missed_target", "ran out of simulated time")
    reasons = [c for c in REASON_CODES if c in codes]
    touching = (np.asarray(trunk).reshape(-1) > 0.5) | (leg_samples.any(axis=1) if leg_force.size else False) \
        | (self_force > criteria.leg_contact_force)
    measures = {
        # When the trunk or a leg link first touched anything (None: never). [s]
        "first_body_contact_s": float(times[np.argmax(touching)]) if np.any(touching) else None,
        "final_xy_error_m": final_xy_error,
        "final_yaw_error_deg": final_yaw_error,
        "max_tilt_deg": max_tilt,
        "trunk_terrain_contacts": trunk_contacts,
        "leg_terrain_contacts": int(np.count_nonzero(leg_samples.any(axis=1))) if leg_force.size else 0,
        "max_leg_link_force_n": worst_leg_force,
        "max_self_contact_force_n": worst_self,
        "max_joint_error_deg": max_joint_error,
        "max_foot_slip_m": float(slip.max()),
    }
    return Verdict(success=not reasons, reasons=reasons, messages=[codes[c] for c in reasons],
                   measures=measures)
