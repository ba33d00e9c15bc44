"""Parameters of the BLC's nonlinear program (paper 000 section II-A), in TOWR's manner
(``towr/src/parameters.cc``): the discretisation, the limits, which constraints are enabled
and which ``(cost, weight)`` pairs are added, each default with a one-line reason, and the
solver settings. One dataclass, YAML-loadable with ``pydrake.common.yaml.yaml_load_typed``.
"""

from __future__ import annotations

import dataclasses
import math

from qz_drake.errors import ConfigError, bad_value

# Every constraint the formulation knows, with the reason it is (or may be) enabled.
CONSTRAINT_REASONS: dict[str, str] = {
    "dynamics": "single-rigid-body dynamics (Eq. 2) at the dynamics samples",
    "base_acceleration": "body accelerations continuous at the spline nodes, so the sampled "
                         "dynamics hold between samples too (TOWR's BaseAcc)",
    "kinematics": "each foot inside its box around the nominal foothold (Eq. 1)",
    "terrain": "stance feet on the ground, swing feet above it (Eq. 4)",
    "force": "normal force in [f_min, f_max] and inside the friction pyramid of the "
             "terrain's tangent frame (Eq. 5)",
    "swing": "swing apex at least swing_apex_height above the terrain under it, and "
             "swing_lift_height above both of the swing's footholds",
    "support": "each free stance foothold on supported ground: the raw heightmap within the "
               "foot's radius plus support_margin stays within support_drop of the foothold's "
               "height (off edges and away from risers; trajopt/support.py)",
    "leg_clearance": "every leg's thigh and shank above the raw ground, from the legs' inverse "
                     "kinematics, at dense samples of stance and swing where the terrain has "
                     "relief (trajopt/leg_clearance.py; paper 000 Fig. 2)",
}
DEFAULT_CONSTRAINTS = ("dynamics", "base_acceleration", "kinematics", "terrain", "force", "swing",
                       "support", "leg_clearance")

# How the straight-line guess chooses footholds (BlcParameters.foothold_guess).
LINEAR_SOLVERS = ("mumps", "spral")
FOOTHOLD_GUESSES = ("auto", "mid", "stance")
# Where the feet stand when a task ends (BlcParameters.terminal_stance).
TERMINAL_STANCES = ("free", "canonical")

# Every cost the formulation knows; none is on by default: Eq. 1-6 is a feasibility problem.
COST_REASONS: dict[str, str] = {
    "base_linear_acceleration": "sum of squared body accelerations at the dynamics samples: "
                                "smoother body motion",
    "base_angular_velocity": "sum of squared Euler-angle rates at the nodes: less wobble",
    "force_rate": "sum of squared force-node derivatives: smoother forces",
}


@dataclasses.dataclass
class BlcParameters:
    """Discretisation, limits, enabled constraints / costs and solver settings of the BLC."""

    # Duration of each body spline polynomial: a node every 0.1 s (TOWR). [s]
    base_node_spacing: float = 0.1
    # Time between samples of the angular half of Eq. 2 (at interval midpoints). Measured on
    # the bench suite with the dense verdict (issue 11): TOWR's 0.1 s left the angular residual
    # between samples at 0.2-3 body weights x 0.3 m (90th percentile); 0.05 s brings it to
    # 0.02-0.04, below the verdict's 0.05; 0.025 s to 0.001 at 3-4x the time. [s]
    dynamics_dt: float = 0.05
    # Time between samples of the linear-momentum half of Eq. 2 (interval midpoints). It is a
    # sparse linear equality, cheap for Ipopt. Measured on the bench suite (the saved 100 Hz
    # samples, away from contact switches): with TOWR's 0.1 s the planned acceleration and the
    # forces disagree between samples by 0.5-3 body weights (90th percentile); 0.05 s brings
    # that to 0.01-0.5 at about the same solve time; 0.025 s to below 0.01 at 2-4x the time. [s]
    linear_dynamics_dt: float = 0.05
    # Time between samples of the kinematic box constraint. TOWR's 0.08 s let stance feet
    # leave their boxes by 3-5 mm between samples on stairs (the dense verdict's limit: 2 mm);
    # 0.04 s keeps them inside on the bench suite at about 1.2x the time. [s]
    kinematics_dt: float = 0.04
    # Where the legs are kept clear (constraint "leg_clearance" active), the program's boxes
    # are this much shorter at the top and the bottom than the robot's (the dense verdict's).
    # Measured (issue 34): with the legs kept clear, stance feet rest against the top or bottom
    # of their boxes on stairs and left them by 2-5 mm between samples, failing 5 of the first
    # 10 Fig. 9 walks on the dense check. [m]
    kinematics_box_inset: float = 0.004
    # Cubic force polynomials per stance phase (TOWR: 3), fewer in a stance where they would
    # be shorter than min_force_polynomial_duration (at least one).
    force_polynomials_per_stance: int = 3
    min_force_polynomial_duration: float = 0.08
    # Pin each stance's first and last force node to zero, as TOWR does (False: forces may
    # jump at touchdown and liftoff, which a duty factor of 0.5 needs for continuous support).
    zero_force_at_touchdown: bool = False
    # Where the force cone of Eq. 5 is imposed: "bernstein", at the four Bezier control points
    # of every force polynomial, which keeps the whole polynomial inside the cone (issue 11:
    # sampled at nodes and midpoints, a stairs plan pulled with -61 N between samples);
    # "samples": at force_samples_per_polynomial points per polynomial only.
    force_points: str = "bernstein"
    # Force-constraint samples per force polynomial (1: at nodes; 2: nodes and midpoints).
    force_samples_per_polynomial: int = 2
    # Least force along the terrain normal inside a stance (paper 000 f_min). [N]
    min_normal_force: float = 5.0
    # Largest normal force; None: each leg's own limit from the robot model. [N]
    max_normal_force: float | None = None
    # Friction coefficient of the pyramid (Eq. 5).
    friction_coefficient: float = 0.5
    # Least height of the swing apex above the terrain under it (foot sphere surface). [m]
    swing_apex_height: float = 0.06
    # Least height of the swing apex above both of the swing's footholds (foot centres); None:
    # not required. Without it a foot crosses a gap or steps down at the height it lifted off
    # (the terrain under the apex is low) and drags along the edge it leaves (a walk's foot
    # slid 6 cm on a trench's edge, session 34). [m]
    swing_lift_height: float | None = 0.06
    # A foot that starts outside its kinematic box keeps the room it stands in until its
    # second stance (formulation.BlcFormulation.box_bounds); False: the box from t = 0, so
    # that such a start cannot be planned.
    relax_start_boxes: bool = True
    # Free x, y offset and rate of each swing's mid node (variables.py): a foot can rise
    # before it moves forward. Without it the horizontal motion is a fixed smooth cubic and,
    # with clearance checked densely (issue 11), TOWR's HyQ block takes 5-20x the iterations.
    free_swing_midpoint: bool = False
    # Swing fractions (0..1) at which the foot must be above the terrain (Eq. 4).
    swing_clearance_fractions: tuple[float, ...] = (0.25, 0.75)
    # And at every multiple of this inside each swing (0: the fractions only). With 0.01 s,
    # the dense verdict's 100 Hz grid, a swing foot is above the terrain wherever the plan is
    # checked or saved (issue 11: with the fractions alone, TOWR's HyQ stairs plan swung a foot
    # 0.10 m deep into a riser). One cheap row per sample. [s]
    swing_clearance_dt: float = 0.01
    # Bound on |roll| and |pitch| of the body at the nodes. [rad]
    max_roll_pitch: float = 0.7
    # Enabled constraints (names in CONSTRAINT_REASONS).
    constraints: tuple[str, ...] = DEFAULT_CONSTRAINTS
    # (cost name, weight) pairs (names in COST_REASONS); empty: a feasibility problem.
    costs: tuple[tuple[str, float], ...] = ()
    # Total time on all feet at the start and at the end of the gait. [s]
    stand_duration: float = 0.2
    # Nominal swing duration; None: the gait's default. [s]
    swing_duration: float | None = None
    # Body speed used to choose a duration when a task has none. [m/s]
    nominal_speed: float = 0.4
    # Wall-time limit of one solve, the paper's 5 s: beyond it the task counts as failed. [s]
    time_limit: float = 5.0
    # Ipopt's convergence tolerance (scaled NLP error).
    tolerance: float = 1e-4
    # Ipopt stops at an "acceptable" point after acceptable_iter consecutive iterates whose
    # constraint violation is below 0.1 violation_tolerance and whose overall error is below
    # acceptable_tol. Eq. 1-6 is a feasibility problem (no cost): once the constraints hold,
    # the dual error Ipopt keeps polishing says nothing about the plan, which the verdict
    # checks anyway. Measured (issue 11): the wave gait and the small quadruped reached
    # feasible points (violation 1e-7) and then ran into the time limit. Ipopt's defaults:
    # 10 tolerance and 15.
    acceptable_tol: float = 1e-3
    acceptable_iter: int = 15
    # Ipopt's absolute constraint violation tolerance.
    constraint_tolerance: float = 1e-4
    # Verdict: a solve succeeds only when every constraint, evaluated at the returned point,
    # is violated by less than this (m, rad, or body weights).
    violation_tolerance: float = 1e-3
    # Dense verdict (trajopt/verdict.py): a converged plan succeeds only if it also holds at
    # every dense sample (False: the sampled constraints alone decide, as before issue 11).
    dense_verdict: bool = True
    # Dense verdict: the plan is checked at this rate, the .npz's. [Hz]
    dense_check_rate: float = 100.0
    # A swing foot may dip this far below the terrain at a dense sample (twice the solver's
    # violation_tolerance: the constraint samples are met to that). [m]
    dense_clearance_tolerance: float = 2e-3
    # A foot may leave its kinematic box by this much at a dense sample. [m]
    dense_box_tolerance: float = 2e-3
    # A stance normal force may fall this far below zero, a tangential force this far outside
    # the friction pyramid, at a dense sample. [body weights]
    dense_force_tolerance: float = 2e-3
    # Single-rigid-body residuals: their dense_residual_percentile-th percentile over the
    # samples farther than dense_switch_margin from a contact switch must stay below
    # dense_residual_limit (issue 11: 0.05 body weights at the 90th percentile). The angular
    # residual (a torque) is divided by m g and by dense_residual_lever, the 0.3 m.
    dense_residual_percentile: float = 90.0
    dense_residual_limit: float = 0.05
    dense_residual_lever: float = 0.3  # [m]
    dense_switch_margin: float = 0.015  # [s]
    # Check and refine (solver.py): a converged plan that fails the dense check is solved
    # again, from where it is, with constraint samples added where it failed, at most this
    # many times, while at least refine_min_time of the time limit is left. Off by default:
    # measured (issue 11), a re-solve fixed a 3-5 mm box excess on two stairs cases in 5-6
    # iterations but wandered off for 40-100 iterations on another stairs case and on the
    # small quadruped; boxes every 0.04 s do the same job without the gamble. [s]
    max_refinements: int = 0
    refine_min_time: float = 0.5
    # Ipopt's initial barrier parameter for such a re-solve (its default 0.1 first pushes the
    # converged point away from its active bounds).
    refine_mu_init: float = 1e-4
    # Phase durations as decision variables (paper 000 Eq. 3, trajopt/timing.py): every global
    # phase of the gait but the stands at both ends gets a time scale within
    # phase_duration_bounds of its nominal length, the scales summing to the task's T. Off by
    # default: the capability dataset labels the BLC with fixed timing (see BENCHMARKS "blc").
    optimize_phase_durations: bool = False
    # Least and largest ratio of an optimised phase duration to its nominal one.
    phase_duration_bounds: tuple[float, float] = (0.5, 2.0)
    # Footholds of the straight-line guess (initial_guess.py): "mid", the best point of the
    # kinematic box around the nominal foothold at mid-stance; "stance", the best point of the
    # boxes at the stance's start and end, with the ground around it level (looks past a gap
    # that fills the mid-stance box); "auto", "stance" for a task whose body travels at least
    # the kinematic box's half length (the window looks along the travel) and "mid" for a
    # turn in place. Measured on 300 trials of the capability collection (issue 11, BENCHMARKS
    # "blc"): with "stance" moves walked 156 of 200 against "mid"'s 146 (11 newly, 1 fewer),
    # turns 72 against 73 of 100 (3 newly, 4 fewer), hence "auto".
    foothold_guess: str = "auto"
    # Support under a stance foot (constraint "support", trajopt/support.py): within the foot's
    # radius plus support_margin the raw ground stays within support_drop of the foothold. The
    # margin covers the tracker's few centimetres of foot error: the demo's seed-0 crossing
    # stood a foot's centre 3 cm from a 0.2 m pit's rim and it slid 9.3 cm off. A drop of 5 cm
    # within 8 cm is also ground steeper than 32 degrees, beyond the friction cone (mu 0.6).
    support_margin: float = 0.05  # [m]
    support_drop: float = 0.05  # [m]
    # Where the feet stand when the task ends (issue 54): "free", wherever the program leaves
    # them in their boxes; "canonical", each foot within terminal_foothold_tolerance (x, y) of
    # the target pose's canonical foothold (trajopt/stance.py: the nominal foothold, moved to
    # the nearest ground terminal_foothold_tolerance clear of unsupported ground; a foot whose
    # move would leave its box stays free), so that a mission ends in the stance a planner's
    # map assumes. [m]
    terminal_stance: str = "free"
    terminal_foothold_tolerance: float = 0.02
    # The dense verdict fails a stance foothold deeper than this inside unsupported ground. [m]
    dense_support_tolerance: float = 0.01
    # Legs' links above the ground (constraint "leg_clearance", trajopt/leg_clearance.py):
    # points every leg_clearance_spacing along each thigh's and shank's collision capsule,
    # sampled every leg_clearance_dt, each at least the capsule's radius plus
    # leg_clearance_margin above the raw ground's highest point within the radius plus
    # leg_clearance_footprint (the field is dilated a cell further, leg_clearance.py). The
    # margin covers the tracker's centimetre of error. Measured (issue 34): a 3 cm footprint
    # failed the 0.2 m / 1.0 m Fig. 5 stairs case and the demo's crossing (a 5.1 cm slip, the
    # bound is 5 cm, after a mission planned with a stretched leg); 2 cm solves both (the
    # demo's largest slip 0.8 cm) and fails the 0.2 m / 2.0 m stairs instead. Rows only where the ground within that reach varies by more than
    # leg_clearance_relief (an edge, a riser, a box): not on flat ground or gentle slopes. [s, m]
    leg_clearance_dt: float = 0.04
    leg_clearance_spacing: float = 0.11
    leg_clearance_footprint: float = 0.02
    # Half-width of a mean that turns the field's steps into ramps (leg_clearance.py; the
    # field is dilated that much further first, so it stays conservative). Off: measured on
    # paper 000 Fig. 2's step, 0.05 m kept front_bend's low knee-in shank 13 cm from the riser
    # out of a plan, and it solved no more of the Fig. 5 stairs. [m]
    leg_clearance_smoothing: float = 0.0
    leg_clearance_margin: float = 0.02
    leg_clearance_relief: float = 0.05
    # One row per leg and sample instead of one per link point: the leg's points' smooth
    # minimum of this sharpness (leg_clearance.LegClearanceSoftminConstraint: never below the
    # points' own bounds, at most log(points) / sharpness more room), J times fewer rows and
    # Jacobian entries. None: a row per point. Not the default: on a noisy map (2 cm cells, 1-2
    # cm pixel noise, tests/trajopt/test_foot_scale_terrain.py) a metre took 104-182 Ipopt
    # iterations at 150-600 / m against 18 with a row per point; in the mean form below 37 at
    # 300, 30 at 1000 (BENCHMARKS "blc and walks, the legs' clearance as one row per leg and
    # sample"). [1/m]
    leg_clearance_softmin: float | None = None
    # With leg_clearance_softmin: each row bounds the leg's log-mean-exp instead of its
    # log-sum-exp (the row's bound -log(J) / sharpness instead of 0), so a point may sink at
    # most log(J) / sharpness below its own bound (2 mm at 1000 / m), where the conservative row
    # keeps every point above it and so asks up to that much more where several points are near
    # their bound at once (likely what slows the noisy metre above: 182 Ipopt iterations, 18
    # with a row per point, 37 in this form at 300 / m, 30 at 1000 / m).
    leg_clearance_softmin_mean: bool = False
    # The dense verdict checks every leg's capsules (every 1.5 cm along them) at its rate and
    # fails a plan whose link dips more than this into the ground (False: no link check). [m]
    dense_link_check: bool = True
    dense_link_tolerance: float = 0.005
    # A gridded map whose cells are at most twice this is solved at the foot's scale
    # (trajopt/terrain.py FootScaleTerrain: the highest cell within 2 x this, a Gaussian mean of
    # sigma this over the same disc; the legs' and supports' fields and the dense verdict's
    # clearances keep the map as given); coarser maps, such as the 5 cm ones of the Fig. 9
    # worlds and the capability scenes, are solved as they are. 0: every map as it is. Issue 52:
    # at 2 cm cells with 1.5 cm of pixel noise every normal of the raw map is a pixel's. [m]
    terrain_foot_scale: float = 0.02
    # Ipopt iteration limit.
    max_iterations: int = 3000
    # Ipopt's linear solver: "mumps", Ipopt 3.14 with MUMPS from the cyipopt wheel on the
    # task's MathematicalProgram (ipopt_mumps.py); "spral", Drake's IpoptSolver, whose pip
    # wheel ships SPRAL only. Measured (issue 11, BENCHMARKS "blc"): MUMPS about twice as fast.
    linear_solver: str = "mumps"
    # numpy BLAS threads during a solve; 0: unchanged. One measured 1.5-2x faster on the
    # 2-core machine (threads.py).
    blas_threads: int = 1
    # Samples of one nonlinear constraint per Drake binding: small bindings keep Drake's
    # dense AutoDiff round trip cheap (its cost grows with the square of a binding's size),
    # few bindings keep the Python calls few. With samples 0.04-0.05 s apart, neighbours share
    # their body nodes and footholds, so 4 samples cost little more than 1: measured
    # interleaved (issue 11), 0.82-0.87x the time of 1 per binding (2: 0.89-0.96; 8 against
    # 4: 0.86-1.01, noise), the same iterations.
    samples_per_binding: int = 4
    # Ipopt console print level (0 = silent).
    print_level: int = 0

    def __post_init__(self):
        for name in ("base_node_spacing", "dynamics_dt", "linear_dynamics_dt", "kinematics_dt",
                     "time_limit", "tolerance", "constraint_tolerance", "violation_tolerance",
                     "stand_duration", "nominal_speed", "dense_check_rate",
                     "dense_clearance_tolerance", "dense_box_tolerance", "dense_force_tolerance",
                     "dense_residual_limit", "dense_residual_lever", "support_margin",
                     "support_drop", "dense_support_tolerance", "leg_clearance_dt",
                     "leg_clearance_spacing", "leg_clearance_relief", "dense_link_tolerance",
                     "leg_clearance_footprint", "terminal_foothold_tolerance"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0):
                raise bad_value(f"blc.{name}", value, "must be positive", ConfigError)
        if not self.friction_coefficient > 0:
            raise bad_value("blc.friction_coefficient", self.friction_coefficient, "must be positive")
        if self.min_normal_force < 0:
            raise bad_value("blc.min_normal_force", self.min_normal_force, "must be non-negative")
        if self.max_normal_force is not None and not self.max_normal_force > self.min_normal_force:
            raise bad_value("blc.max_normal_force", self.max_normal_force,
                            "must exceed min_normal_force")
        if not self.min_force_polynomial_duration >= 0:
            raise bad_value("blc.min_force_polynomial_duration", self.min_force_polynomial_duration,
                            "must be non-negative")
        if int(self.force_polynomials_per_stance) < 1:
            raise bad_value("blc.force_polynomials_per_stance", self.force_polynomials_per_stance,
                            "must be at least 1")
        if int(self.force_samples_per_polynomial) < 1:
            raise bad_value("blc.force_samples_per_polynomial", self.force_samples_per_polynomial,
                            "must be at least 1")
        if int(self.samples_per_binding) < 1:
            raise bad_value("blc.samples_per_binding", self.samples_per_binding, "must be at least 1")
        for name in ("leg_clearance_margin", "leg_clearance_smoothing", "kinematics_box_inset",
                     "terrain_foot_scale"):
            if not getattr(self, name) >= 0:
                raise bad_value(f"blc.{name}", getattr(self, name), "must be non-negative")
        sharpness = self.leg_clearance_softmin
        if sharpness is not None and not (isinstance(sharpness, (int, float)) and not isinstance(sharpness, bool)
                                          and math.isfinite(sharpness) and sharpness > 0):
            raise bad_value("blc.leg_clearance_softmin", self.leg_clearance_softmin,
                            "must be a positive sharpness [1/m] (or null: a row per link point)")
        if not isinstance(self.leg_clearance_softmin_mean, bool):
            raise bad_value("blc.leg_clearance_softmin_mean", self.leg_clearance_softmin_mean,
                            "expected true or false")
        if self.swing_lift_height is not None and not self.swing_lift_height >= 0:
            raise bad_value("blc.swing_lift_height", self.swing_lift_height,
                            "must be non-negative (or null: not required)")
        if not self.swing_clearance_dt >= 0:
            raise bad_value("blc.swing_clearance_dt", self.swing_clearance_dt,
                            "must be non-negative")
        if self.foothold_guess not in FOOTHOLD_GUESSES:
            raise bad_value("blc.foothold_guess", self.foothold_guess,
                            f"expected one of {', '.join(FOOTHOLD_GUESSES)}")
        if self.terminal_stance not in TERMINAL_STANCES:
            raise bad_value("blc.terminal_stance", self.terminal_stance,
                            f"expected one of {', '.join(TERMINAL_STANCES)}", ConfigError)
        if self.linear_solver not in LINEAR_SOLVERS:
            raise bad_value("blc.linear_solver", self.linear_solver,
                            f"expected one of {', '.join(LINEAR_SOLVERS)}")
        if self.force_points not in ("bernstein", "samples"):
            raise bad_value("blc.force_points", self.force_points,
                            "expected 'bernstein' or 'samples'")
        for f in self.swing_clearance_fractions:
            if not 0 < f < 1:
                raise bad_value("blc.swing_clearance_fractions", self.swing_clearance_fractions,
                                "fractions must lie strictly between 0 and 1")
        if self.optimize_phase_durations:
            from qz_drake.trajopt.timing import check_duration_bounds

            self.phase_duration_bounds = check_duration_bounds(self.phase_duration_bounds)
            if self.costs:
                raise bad_value("blc.costs", self.costs, "costs on body accelerations and force "
                                "rates are not defined with optimize_phase_durations",
                                ConfigError)
            if int(self.max_refinements) > 0:
                raise bad_value("blc.max_refinements", self.max_refinements,
                                "must be 0 with optimize_phase_durations", ConfigError)
        self.constraints = tuple(self.constraints)
        for c in self.constraints:
            if c not in CONSTRAINT_REASONS:
                raise bad_value("blc.constraints", c,
                                f"unknown constraint (known: {', '.join(CONSTRAINT_REASONS)})")
        self.costs = tuple((str(n), float(w)) for n, w in self.costs)
        for n, w in self.costs:
            if n not in COST_REASONS:
                raise bad_value("blc.costs", n, f"unknown cost (known: {', '.join(COST_REASONS)})")
            if w < 0:
                raise bad_value(f"blc.costs[{n}]", w, "weights must be non-negative")

    def enabled(self, constraint: str) -> bool:
        return constraint in self.constraints
