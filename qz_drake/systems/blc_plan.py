"""A BLC solution as a mission plan: the BodyFeetTrajectory the InverseKinematicsTracker follows,
and the mission planner that asks the BLC (paper 000, section II-A) for one from the measured
state.

The BLC optimises the single rigid body's CoM; the tracker needs the base link's origin:
p_W_base = p_W_CoM - R_WB com_B. Times are shifted to simulation time.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
from pydrake.math import RollPitchYaw

from qz_drake.errors import ConfigError, bad_value
from qz_drake.robot.params import NUM_LEGS
from qz_drake.systems.mission_sequencer import MissionStart


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


def expected_end(plan) -> MissionStart:
    """The mission start a plan is expected to end in: its base pose and feet at end_time."""
    t = plan.end_time
    p = plan.base_position(t)
    rpy = plan.base_rpy(t)
    return MissionStart(time=t, xy_yaw=(float(p[0]), float(p[1]), float(rpy[2])),
                        feet_W=np.asarray(plan.foot_positions(t), dtype=float), base_z=float(p[2]),
                        roll_pitch=(float(rpy[0]), float(rpy[1])))


class ChainedPlan:
    """Two or more BlcPlans one after the other, each starting where the one before ends: one
    mission that the BLC ladder's ``split`` rung planned in parts. It reads like a BlcPlan (the
    tracker, the sequencers and expected_end see one plan from the first part's start to the
    last part's end); ``solution`` is the last part's and ``parts`` lists them all."""

    def __init__(self, parts):
        parts = list(parts)
        if len(parts) < 2:
            raise bad_value("parts", len(parts), "a chained plan needs at least two", ConfigError)
        for before, after in zip(parts, parts[1:]):
            if abs(after.start_time - before.end_time) > 1e-9:
                raise bad_value("parts", f"a part starting at {after.start_time:g} s",
                                f"expected the end of the one before, {before.end_time:g} s", ConfigError)
        self.parts = parts
        self.solution = parts[-1].solution
        self.topology = parts[-1].topology
        self.start_time = parts[0].start_time
        self.end_time = parts[-1].end_time

    def __deepcopy__(self, memo):
        return self  # immutable, as its parts

    def _part(self, t: float) -> int:
        for k, part in enumerate(self.parts[:-1]):
            if float(t) < part.end_time:
                return k
        return len(self.parts) - 1

    def base_rpy(self, t: float) -> np.ndarray:
        return self.parts[self._part(t)].base_rpy(t)

    def base_position(self, t: float) -> np.ndarray:
        return self.parts[self._part(t)].base_position(t)

    def foot_positions(self, t: float) -> np.ndarray:
        return self.parts[self._part(t)].foot_positions(t)

    def foot_forces(self, t: float) -> np.ndarray:
        return self.parts[self._part(t)].foot_forces(t)

    def contact(self, t: float) -> np.ndarray:
        return self.parts[self._part(t)].contact(t)

    def stance_start(self, leg: int, t: float) -> float | None:
        k = self._part(t)
        start = self.parts[k].stance_start(leg, t)
        # A foot standing through the junction touched down in the part before (each part
        # begins and ends with every foot in stance, on the same footholds).
        while start is not None and k > 0 and abs(start - self.parts[k].start_time) <= 1e-9:
            k -= 1
            earlier = self.parts[k].stance_start(leg, self.parts[k].end_time)
            if earlier is None:
                break
            start = earlier
        return start


# A rung of the BLC ladder: "cycles+N", the mission N tripod cycles longer; "split" or "split+N",
# the mission in two halves (the nearer one first, each timed by the mission rule, N cycles
# longer), chained; "short", its target SHORTEN nearer along the way (the route's next mission
# starts from where the robot stands, so a mission may end a little short; measured on the
# Fig. 9 world stairs-hard-3, a 1 m mission ending 0.40 m before the first riser was refused on
# every other rung and planned ending 0.05 m nearer or farther); "free", the mission with its
# end stance left to the BLC (BlcParameters.terminal_stance "free"), for a BLC asked to end in
# the canonical stance (trajopt/stance.py), which a mission down a flight may not reach.
_RUNG = re.compile(r"^(cycles|split|short|free)(?:\+([1-4]))?$")
RUNG_HELP = "expected 'cycles+N', 'split', 'split+N', 'short' or 'free' (N = 1..4)"
SHORTEN = 0.1  # [m]


def parse_ladder(ladder, field: str = "blc.ladder") -> tuple[str, ...]:
    """The BLC ladder's rungs from a sequence or a comma-separated string ("" or None: none);
    a malformed or repeated rung raises QzError naming ``field``."""
    if ladder is None:
        return ()
    if isinstance(ladder, str):
        ladder = [rung.strip() for rung in ladder.split(",") if rung.strip()]
    rungs = []
    for rung in ladder:
        match = _RUNG.match(rung) if isinstance(rung, str) else None
        if match is None or (match.group(1) == "cycles" and match.group(2) is None) or \
                (match.group(1) in ("short", "free") and match.group(2) is not None):
            raise bad_value(field, rung, RUNG_HELP, ConfigError)
        if rung in rungs:
            raise bad_value(field, rung, "is given twice", ConfigError)
        rungs.append(rung)
    return tuple(rungs)


def retry_ladder(retries: int) -> tuple[str, ...]:
    """The ladder of ``mission_retries``: one tripod cycle longer per retry."""
    return tuple(f"cycles+{k}" for k in range(1, int(retries) + 1))


def _rung_kind(rung: str) -> tuple[str, int]:
    match = _RUNG.match(rung)
    if match is None:
        raise bad_value("rung", rung, RUNG_HELP, ConfigError)
    return match.group(1), int(match.group(2) or 0)


def blc_mission_planner(heightmap, params, control, blc_params=None):
    """A MissionSequencer planner that solves the BLC from the measured base pose and feet.

    ``control`` gives the mission timing (``speed`` [m/s], ``phase_duration`` [s]); blc_params
    the solver's BlcParameters (None: defaults); a call's ``extra_cycles`` lengthens the
    mission by that many tripod cycles (a retry) and its ``rung`` (a rung of the BLC ladder,
    parse_ladder; "" the mission as asked) says how else to solve it. The returned callable
    keeps its statistics in ``plan.stats``, its latest BlcSolution (failed or not) in
    ``plan.last_solution`` and the Ipopt iterations of its last call (all its solves) in
    ``plan.last_iterations``."""
    from qz_drake.robot.topology import get_topology
    from qz_drake.trajopt.robot_model import qingzhui
    from qz_drake.trajopt.solver import BlcTask, solve_blc

    from qz_drake.trajopt.parameters import BlcParameters

    stand_duration = (blc_params or BlcParameters()).stand_duration
    # The "free" rung's parameters: the same with the end stance left to the BLC.
    free_params = dataclasses.replace(blc_params or BlcParameters(), terminal_stance="free")
    robots = {}
    stats = {"solves": 0, "failures": 0, "solve_time_s": 0.0}

    def plan(start, target, topology, start_time, extra_cycles: int = 0, rung: str = ""):
        kind, cycles = _rung_kind(rung) if rung else ("", 0)
        if kind == "short":
            x0, y0, _ = start.xy_yaw
            length = math.hypot(target[0] - x0, target[1] - y0)
            if length < 2 * SHORTEN:
                plan.last_iterations = 0
                return None, f"BLC: a mission of {length:.2f} m is too short to end {SHORTEN:g} m nearer"
            k = 1.0 - SHORTEN / length
            target = (x0 + k * (target[0] - x0), y0 + k * (target[1] - y0), target[2])
        if kind == "free":
            planned, reason = solve(start, target, topology, start_time, extra_cycles, free_params)
            plan.last_iterations = int(plan.last_solution.iterations)
            return planned, reason
        if kind != "split":
            planned, reason = solve(start, target, topology, start_time, extra_cycles + cycles)
            plan.last_iterations = int(plan.last_solution.iterations)
            return planned, reason
        # Halfway in x, y and heading; each half timed by the mission rule.
        x0, y0, yaw0 = start.xy_yaw
        turn = math.remainder(target[2] - yaw0, 2 * math.pi)
        middle = (0.5 * (x0 + target[0]), 0.5 * (y0 + target[1]), yaw0 + 0.5 * turn)
        first, reason = solve(start, middle, topology, start_time, extra_cycles + cycles)
        iterations = int(plan.last_solution.iterations)
        if first is None:
            plan.last_iterations = iterations
            return None, f"{reason} (first half)"
        second, reason = solve(expected_end(first), target, topology, first.end_time,
                               extra_cycles + cycles)
        plan.last_iterations = iterations + int(plan.last_solution.iterations)
        if second is None:
            return None, f"{reason} (second half)"
        return ChainedPlan([first, second]), ""

    def solve(start, target, topology, start_time, extra_cycles, solver_params=blc_params):
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
        solution = solve_blc(task, robot, heightmap, solver_params)
        plan.last_solution = solution
        stats["solves"] += 1
        stats["solve_time_s"] += solution.solve_time
        if not solution.success:
            stats["failures"] += 1
            return None, f"BLC: {solution.reason or solution.status}"
        return BlcPlan(solution, start_time, get_topology(topology, params)), ""

    plan.stats = stats
    plan.last_solution = None
    plan.last_iterations = 0
    return plan
