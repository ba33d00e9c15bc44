"""A BLC solution as a mission plan: the BodyFeetTrajectory the InverseKinematicsTracker follows,
and the mission planner that asks the BLC (paper 000, section II-A) for one from the measured
state.

The BLC optimises the single rigid body's CoM; the tracker needs the base link's origin:
p_W_base = p_W_CoM - R_WB com_B. Times are shifted to simulation time.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.math import RollPitchYaw

from qz_drake.robot.params import NUM_LEGS


class BlcPlan:
    """A BlcSolution seen from simulation time, with the base link in place of the CoM."""

    def __init__(self, solution, start_time: float, topology):
        self.solution = solution
        self.topology = topology
        self.start_time = float(start_time)
        self.end_time = self.start_time + float(solution.duration)
        self._com_B = np.asarray(solution.robot.com_B, dtype=float)

    def __deepcopy__(self, memo):
        return self  # immutable; Drake copies abstract values often

    def _local(self, t: float) -> float:
        # min(max()) is np.clip for a scalar, without its array machinery (called per update).
        return float(min(max(float(t) - self.start_time, 0.0), float(self.solution.duration)))

    def base_rpy(self, t: float) -> np.ndarray:
        return self.solution.body_rpy.value(self._local(t)).ravel()

    def base_position(self, t: float) -> np.ndarray:
        R = RollPitchYaw(self.base_rpy(t)).ToRotationMatrix().matrix()
        return self.solution.body_position.value(self._local(t)).ravel() - R @ self._com_B

    def foot_positions(self, t: float) -> np.ndarray:
        tl = self._local(t)
        return np.array([pp.value(tl).ravel() for pp in self.solution.foot_positions])

    def foot_forces(self, t: float) -> np.ndarray:
        tl = self._local(t)
        return np.array([pp.value(tl).ravel() for pp in self.solution.foot_forces])

    def contact(self, t: float) -> np.ndarray:
        return self.solution.contact_schedule.contact_at(self._local(t))

    def stance_start(self, leg: int, t: float) -> float | None:
        tl = self._local(t)
        for start, stop in self.solution.contact_schedule.stance_intervals(leg):
            if start - 1e-9 <= tl <= stop + 1e-9:
                return self.start_time + start
        return None


def blc_mission_planner(heightmap, params, control, blc_params=None):
    """A MissionSequencer planner that solves the BLC from the measured base pose and feet.

    ``control`` gives the mission timing (``speed`` [m/s], ``phase_duration`` [s]); blc_params
    the solver's BlcParameters (None: defaults); a call's ``extra_cycles`` lengthens the
    mission by that many tripod cycles (a retry). The returned callable keeps its statistics in
    ``plan.stats`` and its latest BlcSolution (failed or not) in ``plan.last_solution``."""
    from qz_drake.robot.topology import get_topology
    from qz_drake.trajopt.robot_model import qingzhui
    from qz_drake.trajopt.solver import BlcTask, solve_blc

    from qz_drake.trajopt.parameters import BlcParameters

    stand_duration = (blc_params or BlcParameters()).stand_duration
    robots = {}
    stats = {"solves": 0, "failures": 0, "solve_time_s": 0.0}

    def plan(start, target, topology, start_time, extra_cycles: int = 0):
        robot = robots.setdefault(topology, qingzhui(topology))
        x0, y0, yaw0 = start.xy_yaw
        com_B = np.asarray(robot.com_B, dtype=float)
        base_z = start.base_z if start.base_z is not None else (
            float(np.mean(start.feet_W[:, 2])) - params.foot_radius + params.standing_height)
        # The measured attitude: on stairs the robot stands pitched, and its measured feet are
        # inside their boxes only for that attitude.
        rpy0 = (start.roll_pitch[0], start.roll_pitch[1], yaw0)
        R0 = RollPitchYaw(rpy0).ToRotationMatrix().matrix()
        com = np.array([x0, y0, base_z]) + R0 @ com_B
        c1, s1 = math.cos(target[2]), math.sin(target[2])
        com_target = (target[0] + c1 * com_B[0] - s1 * com_B[1], target[1] + s1 * com_B[0] + c1 * com_B[1], target[2])
        dist = math.hypot(target[0] - x0, target[1] - y0)
        # Round to whole tripod cycles of two phases.
        cycle = 2 * control.phase_duration
        duration = max(dist / control.speed, 1.2)
        # A turn of more than 60 deg gets two tripod cycles per 45 deg: a 90 deg turn in place
        # in the 1.2 s of a 45 deg one left the feet 0.17 m outside their boxes (a CapPlanner
        # walk's first mission failed on it). Up to 60 deg (the capability trials turn 45 deg,
        # a little more as measured) missions keep the timing they were labelled with.
        turn = abs(math.remainder(target[2] - yaw0, 2 * math.pi))
        if turn > math.radians(60.0):
            duration = max(duration, turn / (math.pi / 4) * 2 * cycle)
        duration = cycle * max(1, round(duration / cycle))
        # Both tripods must step at least once between the BLC's stands at start and end.
        duration = max(duration, 2 * stand_duration + cycle)
        # A retry of a mission that failed to plan: the same mission, slower.
        duration += extra_cycles * cycle
        task = BlcTask(target=com_target, start_position=tuple(com), start_rpy=rpy0,
                       start_feet=np.asarray(start.feet_W, dtype=float)[:NUM_LEGS], topology=topology,
                       duration=duration)
        solution = solve_blc(task, robot, heightmap, blc_params)
        plan.last_solution = solution
        stats["solves"] += 1
        stats["solve_time_s"] += solution.solve_time
        if not solution.success:
            stats["failures"] += 1
            return None, f"BLC: {solution.reason or solution.status}"
        return BlcPlan(solution, start_time, get_topology(topology, params)), ""

    plan.stats = stats
    plan.last_solution = None
    return plan
