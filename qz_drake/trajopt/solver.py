"""``solve_blc``: one BLC solve, from a task to a BlcSolution with an honest verdict
(paper 000 section II-A; the 5 s limit of its section III-A).

The task's Drake MathematicalProgram is solved by Ipopt: by default Ipopt 3.14 with MUMPS from
the cyipopt wheel (ipopt_mumps.py, about twice as fast on these programs), or with
``linear_solver: spral`` by Drake's IpoptSolver, whose pip wheel ships SPRAL only. Settings: the
limited-memory Hessian (no exact Hessian for Python constraints), a wall-time limit, and
tolerances from BlcParameters. After Ipopt returns, every constraint is evaluated at the returned
point; the solve succeeds only if Ipopt converged and the worst violation is below
``violation_tolerance``, and the plan then also holds at every 100 Hz sample (verdict.py:
swing feet above the terrain, stance feet in their boxes, stance forces pushing and inside the
friction pyramid, single-rigid-body residuals small). Optionally (``max_refinements``) a plan
that fails only the dense check is solved again with constraint samples added where it failed.
Nothing a task can do raises here: bad inputs (a wrong number of feet, an unknown gait) raise
QzError before solving; a task that cannot be solved is a result.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from pydrake.solvers import IpoptSolver, SolverOptions

from qz_drake.errors import ConfigError, bad_value
from qz_drake.trajopt import ipopt_mumps
from qz_drake.trajopt.formulation import BlcFormulation
from qz_drake.trajopt.gait import make_gait
from qz_drake.trajopt.initial_guess import (shifted_solution_guess, straight_line_guess,
                                            terrain_fitted_pose)
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import RobotModel, qingzhui
from qz_drake.trajopt.solution import BlcSolution
from qz_drake.trajopt.terrain import as_terrain
from qz_drake.trajopt.threads import blas_threads
from qz_drake.trajopt.timing import PhaseLayout
from qz_drake.trajopt.verdict import dense_check

# Seconds of the time limit kept back from Ipopt for its last iteration and the verdict.
VERDICT_MARGIN = 0.25

CONVERGED = ("Success", "Stop at acceptable point", "Feasible point found")


@dataclasses.dataclass
class BlcTask:
    """What the BLC is asked to do (DESIGN.md): from a start pose and footholds to a local
    target within a duration, in a topology and a gait.

    Positions are of the CoM (the single rigid body's origin), in the world frame.
    """

    # Local target of the CoM and the body's heading: (x [m], y [m], yaw [rad]).
    target: tuple[float, float, float]
    # CoM at the start; None: standing nominally over (0, 0) on the terrain. [m]
    start_position: tuple[float, float, float] | None = None
    # Body roll, pitch, yaw at the start; roll and pitch ignored when start_position is None. [rad]
    start_rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Foot-sphere centres at the start, (L, 3); None: nominal footholds on the terrain. [m]
    start_feet: np.ndarray | None = None
    # Qingzhui topology (used when solve_blc builds the robot).
    topology: str = "nominal"
    # Duration T; None: chosen from the distance and BlcParameters.nominal_speed. [s]
    duration: float | None = None
    # Gait name; None: the robot's default.
    gait: str | None = None
    # CoM velocity at the start. [m/s]
    start_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)


def standing_start(robot: RobotModel, terrain, x: float = 0.0, y: float = 0.0, yaw: float = 0.0):
    """(CoM position, rpy, feet (L, 3)) of the robot standing nominally over (x, y) on the
    terrain, its body following the terrain's plane under its feet."""
    terrain = as_terrain(terrain)
    z, roll, pitch = terrain_fitted_pose(robot, terrain, np.array([[x, y]]), np.array([yaw]))
    rpy = np.array([roll[0], pitch[0], yaw])
    c, s = math.cos(yaw), math.sin(yaw)
    feet_B = robot.nominal_footholds
    feet = np.column_stack([x + c * feet_B[:, 0] - s * feet_B[:, 1],
                            y + s * feet_B[:, 0] + c * feet_B[:, 1]])
    h = terrain.height(feet[:, 0], feet[:, 1])
    feet = np.column_stack([feet, h + robot.foot_radius])
    return np.array([x, y, z[0]]), rpy, feet


def _resolve(task: BlcTask, robot: RobotModel, terrain, params: BlcParameters):
    if task.start_position is None:
        start, rpy, feet = standing_start(robot, terrain, 0.0, 0.0, task.start_rpy[2])
    else:
        start = np.asarray(task.start_position, dtype=float).reshape(3)
        rpy = np.asarray(task.start_rpy, dtype=float).reshape(3)
        feet = None
    if task.start_feet is not None:
        feet = np.asarray(task.start_feet, dtype=float)
        if feet.shape != (robot.num_legs, 3):
            raise bad_value("task.start_feet", f"array of shape {feet.shape}",
                            f"expected ({robot.num_legs}, 3) for {robot.name}")
    elif feet is None:
        _, _, feet = standing_start(robot, terrain, start[0], start[1], rpy[2])
    if task.start_feet is not None and np.all(np.isfinite(feet)):
        # Feet measured in simulation stand a few mm inside the terrain (contact penetration:
        # 2-3 mm on the grid_map mesh). The start footholds are fixed, so a swing that leaves
        # one must climb out of the ground before the first clearance sample 0.01 s later:
        # measured on the demo's second mission, Ipopt then stalled at a 4e-5 swing violation
        # for 300 iterations; lifted onto the surface, it converged in 5. A foot is a sphere
        # resting on the terrain: its centre is put back radius above the surface.
        surface = np.asarray(terrain.height(feet[:, 0], feet[:, 1]), dtype=float) + robot.foot_radius
        feet = feet.copy()
        feet[:, 2] = np.maximum(feet[:, 2], surface)
    target = np.asarray(task.target, dtype=float).reshape(-1)
    if target.shape != (3,) or not np.all(np.isfinite(target)):
        raise bad_value("task.target", task.target, "expected finite (x, y, yaw)")
    for name, value in (("task.start_position", start), ("task.start_rpy", rpy),
                        ("task.start_feet", feet)):
        if not np.all(np.isfinite(value)):
            raise bad_value(name, value.tolist(), "must be finite")
    duration = task.duration
    if duration is None:
        distance = float(np.hypot(*(target[:2] - start[:2])))
        duration = 2 * params.stand_duration + max(distance / params.nominal_speed, 0.6)
        duration = math.ceil(duration * 10 - 1e-9) / 10
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise bad_value("task.duration", duration, "must be a positive number of seconds")
    gait = task.gait or robot.gaits[0]
    schedule = make_gait(gait, robot.num_legs, float(duration),
                         swing_duration=params.swing_duration, stand_duration=params.stand_duration)
    return start, rpy, feet, target, schedule


def reachable_distance(robot: RobotModel, schedule, margin: float = 0.01) -> float:
    """An upper bound on how far the CoM can move over the schedule with every stance foot in
    its kinematic box (Eq. 1): over a stance of foot i the CoM stays within rho_i of the fixed
    foot, rho_i the farthest point of the box around the nominal foothold (any rotation), so it
    moves at most 2 rho_i; along a chain of overlapping stances covering [0, T] the bounds add
    up, and the cheapest chain is the bound. ``margin`` per stance covers the verdict's
    tolerances. inf when no chain covers [0, T] (a flight phase). [m]"""
    n = np.abs(robot.nominal_footholds) + robot.box_half_sizes
    rho = np.linalg.norm(n, axis=1) + margin
    intervals = [(a, b, 2 * rho[leg]) for leg in range(schedule.num_legs)
                 for a, b in schedule.stance_intervals(leg)]
    T = schedule.duration
    # Cheapest chain from t = 0 to t = T (intervals sorted by start; a few dozen of them).
    intervals.sort()
    best = [math.inf] * len(intervals)
    for k, (a, b, cost) in enumerate(intervals):
        if a <= 1e-12:
            best[k] = cost
        for j in range(k):
            if intervals[j][1] >= a - 1e-12 and best[j] + cost < best[k]:
                best[k] = best[j] + cost
    ends = [best[k] for k, (_, b, _) in enumerate(intervals) if b >= T - 1e-12]
    return min(ends) if ends else math.inf


def ipopt_options(params: BlcParameters, wall_time: float) -> dict:
    """Ipopt's options for a solve with ``wall_time`` seconds left, by name."""
    options = {
        "hessian_approximation": "limited-memory",
        "linear_solver": params.linear_solver,
        "tol": float(params.tolerance),
        "constr_viol_tol": float(params.constraint_tolerance),
        "acceptable_tol": float(params.acceptable_tol),
        "acceptable_iter": int(params.acceptable_iter),
        "acceptable_constr_viol_tol": 0.1 * float(params.violation_tolerance),
        "max_iter": int(params.max_iterations),
        "max_wall_time": max(float(wall_time), 0.05),
        "max_cpu_time": max(float(wall_time), 0.05) * 4,
        "print_level": int(params.print_level),
    }
    if params.linear_solver == "spral":
        # Measured on the BLC's KKT systems (about 2000 rows): SPRAL's default matching-based
        # scaling and supernode amalgamation (nemin 32) made factorisation 3-5x slower.
        options["spral_scaling"] = "none"
        options["spral_nemin"] = 4
    else:
        # Measured on the bench cases, interleaved (issue 11, BENCHMARKS "blc"): an AMD ordering
        # without MUMPS's scalings, 0.9x the time in the same iterations, every case the same.
        options["mumps_pivot_order"] = 0
        options["mumps_scaling"] = 0
        options["mumps_permuting_scaling"] = 0
    return options


def _drake_ipopt(program, x0, options: dict) -> tuple[np.ndarray, str, int]:
    """Drake's IpoptSolver (SPRAL) on the program: (x, status, iterations)."""
    solver_options = SolverOptions()
    for key, value in options.items():
        solver_options.SetOption(IpoptSolver.id(), key, value)
    result = IpoptSolver().Solve(program.prog, x0, solver_options)
    status = result.get_solver_details().ConvertStatusToString()
    return result.GetSolution(program.x_vars), status, max(program.counter["jacobians"] - 1, 0)


def _mumps_ipopt(program, x0, options: dict) -> tuple[np.ndarray, str, int]:
    """Ipopt with MUMPS (ipopt_mumps) on the same program: (x, status, iterations)."""
    if not ipopt_mumps.available():
        raise bad_value("blc.linear_solver", "mumps", "needs the package cyipopt-wheels "
                        "(installed by `make setup`); or choose 'spral'", ConfigError)
    result = ipopt_mumps.solve(program.prog, x0, options, program.vectorised)
    return result.x, result.status, result.iterations


def solve_blc(task: BlcTask, robot: RobotModel | None = None, terrain=None,
              params: BlcParameters | None = None, initial_guess=None, *,
              time_shift: float = 0.0) -> BlcSolution:
    """Solves the BLC's nonlinear program for a task (paper 000 Eq. 1-6).

    Args:
        task: the BlcTask.
        robot: a RobotModel; None: Qingzhui in ``task.topology``.
        terrain: a TerrainModel, a gridded heightmap (heights, resolution, origin) or None (flat).
        params: BlcParameters; None: the defaults.
        initial_guess: None (straight line), a previous BlcSolution (warm start, sampled from
            ``time_shift`` on) or a decision vector of the right size.
        time_shift: where to start reading a previous solution. [s]

    Returns:
        A BlcSolution; success is False (with a reason) when the task could not be solved.
    """
    clock = time.perf_counter()
    params = params or BlcParameters()
    robot = robot or qingzhui(task.topology)
    terrain = as_terrain(terrain, params.terrain_foot_scale)
    start, rpy, feet, target, schedule = _resolve(task, robot, terrain, params)
    layout = PhaseLayout(schedule, params) if params.optimize_phase_durations else None
    formulation = BlcFormulation(robot, terrain, params, schedule, start_position=start,
                                 start_rpy=rpy, start_feet=feet, target=target,
                                 start_velocity=task.start_velocity, layout=layout)
    if initial_guess is None:
        x0 = straight_line_guess(formulation)
    elif isinstance(initial_guess, BlcSolution):
        x0 = shifted_solution_guess(formulation, initial_guess, time_shift)
    else:
        x0 = np.asarray(initial_guess, dtype=float).reshape(-1)
        if x0.shape != (formulation.variables.num_vars,):
            raise bad_value("initial_guess", f"vector of {x0.size} values",
                            f"expected {formulation.variables.num_vars}", ConfigError)
    # A target beyond what the boxes let the body travel in this schedule fails at once.
    distance = float(np.hypot(*(np.asarray(target[:2]) - start[:2])))
    reach = reachable_distance(robot, schedule)
    if distance > reach:
        solution = _verdict(formulation, x0, "Not solved", 0, clock, 0.0)
        solution.reason = (f"infeasible: target {distance:.2f} m away, the kinematic boxes let "
                           f"the body travel at most {reach:.2f} m in {schedule.duration:g} s "
                           f"with this gait (no Ipopt solve; the trajectories are the guess)")
        return solution
    iterations, ipopt_time, extra = 0, 0.0, {}
    for refinement in range(int(params.max_refinements) + 1):
        mumps = params.linear_solver == "mumps"
        program = formulation.build_program(drake_ipopt=not mumps)
        # Ipopt checks its wall-time limit once per iteration; the margin covers the iteration
        # in flight and the verdict, so that the whole call ends within params.time_limit.
        remaining = params.time_limit - (time.perf_counter() - clock) - VERDICT_MARGIN
        options = ipopt_options(params, remaining)
        if refinement:
            # From a converged point: a small barrier parameter keeps Ipopt near it.
            options["mu_init"] = float(params.refine_mu_init)
        ipopt_clock = time.perf_counter()
        with blas_threads(params.blas_threads):
            x, status, count = (_mumps_ipopt if mumps else _drake_ipopt)(program, x0, options)
        ipopt_time += time.perf_counter() - ipopt_clock
        iterations += count
        solution = _verdict(formulation, x, status, iterations, clock, ipopt_time)
        solution.refinements = refinement
        # Check and refine: a plan that meets every sampled constraint but fails the dense
        # check gets constraint samples where it failed and is solved again from where it is.
        sampled_ok = status in CONVERGED and solution.max_violation <= params.violation_tolerance
        dense = solution.dense
        left = params.time_limit - (time.perf_counter() - clock)
        if (solution.success or not sampled_ok or dense is None or not dense.refine_times
                or left < params.refine_min_time):
            break
        for key, times in dense.refine_times.items():
            extra[key] = np.concatenate([extra.get(key, np.zeros(0)), times])
        formulation = BlcFormulation(robot, terrain, params, schedule, start_position=start,
                                     start_rpy=rpy, start_feet=feet, target=target,
                                     start_velocity=task.start_velocity, extra_samples=extra)
        x0 = x
    return solution


def realize(formulation: BlcFormulation, x: np.ndarray) -> tuple[BlcFormulation, np.ndarray]:
    """A formulation with free phase durations and its point -> the plan at the optimised
    durations: its (constraint-free) formulation and decision vector (timing.py). Others are
    returned as they are."""
    layout = formulation.layout
    if layout is None:
        return formulation, x
    v = formulation.variables
    scales = np.nan_to_num(np.asarray(x, dtype=float)[v.phase_scale], nan=1.0)
    durations = layout.durations(scales)
    f = formulation
    realized = BlcFormulation(f.robot, f.terrain, f.params, layout.schedule(durations),
                              start_position=f.start_position, start_rpy=f.start_rpy,
                              start_feet=f.start_feet,
                              target=(f.target[0], f.target[1], f.target_yaw),
                              start_velocity=f.start_velocity,
                              realized=(layout, layout.boundaries(durations)))
    x_real = np.asarray(x, dtype=float).copy()
    x_real[v.phase_scale] = durations / layout.nominal_durations
    return realized, layout.realize(v, x_real)


def _verdict(formulation: BlcFormulation, x: np.ndarray, status: str, iterations: int,
             clock: float, ipopt_time: float) -> BlcSolution:
    params, robot = formulation.params, formulation.robot
    finite = bool(np.all(np.isfinite(x)))
    if finite:
        violations = formulation.violations(x)
        name, worst, where = max(violations, key=lambda item: item[1])
    else:
        violations, name, worst, where = [], "decision vector", math.inf, "non-finite values"
    num_constraints = formulation.num_constraints
    # With free phase durations the constraints are those of the program in nominal time; the
    # dense check and the trajectories are those of the plan at the optimised durations.
    formulation, x = realize(formulation, x)
    v = formulation.variables
    converged = status in CONVERGED
    feasible = worst <= params.violation_tolerance
    reasons = []
    if not converged:
        reasons.append(f"Ipopt: {status}")
    if not feasible:
        reasons.append(f"max violation {worst:.3g} > {params.violation_tolerance:g} "
                       f"in {name} ({where})")
    # The dense check runs on every finite plan (its figures describe failed plans too) but
    # only decides for converged, feasible ones.
    dense = dense_check(formulation, x) if finite else None
    dense_passed = dense is None or dense.passed or not params.dense_verdict
    if converged and feasible and not dense_passed:
        reasons.append("dense check: " + "; ".join(dense.failures))
    elapsed = time.perf_counter() - clock
    if elapsed > params.time_limit and (not converged or not feasible):
        reasons.append(f"time limit {params.time_limit:g} s")
    xs = x if finite else np.nan_to_num(x)
    force_pps = [spline.to_piecewise_polynomial(xs, robot.weight) for spline in v.foot_force]
    return BlcSolution(
        success=converged and feasible and dense_passed, status=status, reason="; ".join(reasons),
        solve_time=elapsed, iterations=iterations, max_violation=float(worst),
        num_variables=v.num_vars, num_constraints=num_constraints,
        duration=v.duration,
        body_position=v.base_position.to_piecewise_polynomial(xs),
        body_rpy=v.base_rpy.to_piecewise_polynomial(xs),
        foot_positions=[s.to_piecewise_polynomial(xs) for s in v.foot_position],
        foot_forces=force_pps, contact_schedule=formulation.schedule, robot=robot,
        terrain=formulation.terrain, mu=params.friction_coefficient,
        violations={n: (val, w) for n, val, w in violations}, ipopt_time=ipopt_time, x=x,
        params=params, dense=dense)
