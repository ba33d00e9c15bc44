"""Phase durations as decision variables (issue 11, paper 000 Eq. 3; trajopt/timing.py): the
constraints that read the durations have exact Jacobians in the duration columns, the plan at
the optimised durations is the program's plan in real time, Eq. 3 holds per foot, and a solve
with free durations holds at every 100 Hz sample."""

import numpy as np
import pytest

from qz_drake.errors import QzError
from qz_drake.terrain import make_terrain
from qz_drake.trajopt import terrain as tt
from qz_drake.trajopt.formulation import BlcFormulation
from qz_drake.trajopt.gait import make_gait
from qz_drake.trajopt.initial_guess import straight_line_guess
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import qingzhui
from qz_drake.trajopt.solver import BlcTask, realize, solve_blc, standing_start
from qz_drake.trajopt.timing import PhaseLayout
from tests.trajopt.npz_checks import assert_plan_holds
from tests.trajopt.test_blc_constraints import _check_jacobian

PARAMS = BlcParameters(optimize_phase_durations=True, time_limit=60.0)


def _formulation(terrain, duration=1.6, target=(0.5, 0.1, 0.3), params=PARAMS):
    robot = qingzhui("nominal")
    schedule = make_gait("tripod", robot.num_legs, duration, stand_duration=params.stand_duration)
    start, rpy, feet = standing_start(robot, terrain)
    layout = PhaseLayout(schedule, params)
    return BlcFormulation(robot, terrain, params, schedule, start_position=start, start_rpy=rpy,
                          start_feet=feet, target=target, layout=layout)


@pytest.fixture(scope="module")
def perturbed():
    """A formulation with free durations on rough ground, every variable perturbed, the
    free phases' scales far from 1 and the scales summing to T (a point of the program)."""
    heightmap = make_terrain("rough", seed=3, amplitude=0.06, correlation_length=0.3)
    f = _formulation(tt.as_terrain(heightmap))
    v, layout = f.variables, f.layout
    x = straight_line_guess(f)
    rng = np.random.default_rng(1)
    x = x + 0.03 * rng.standard_normal(len(x))
    scales = np.ones(layout.num_phases)
    scales[layout.free] = rng.uniform(0.6, 1.6, layout.free.sum())
    x[v.phase_scale] = layout.durations(scales) / layout.nominal_durations
    return f, x


def test_layout_phases_bounds_and_eq3(perturbed):
    f, x = perturbed
    layout, v = f.layout, f.variables
    # Tripod over 1.6 s: stand 0.2, four 0.3 s swing slots, stand 0.2.
    np.testing.assert_allclose(layout.nominal_durations, [0.2, 0.3, 0.3, 0.3, 0.3, 0.2])
    np.testing.assert_array_equal(layout.free, [False, True, True, True, True, False])
    np.testing.assert_array_equal(f.lower[v.phase_scale], [1.0, 0.5, 0.5, 0.5, 0.5, 1.0])
    np.testing.assert_array_equal(f.upper[v.phase_scale], [1.0, 2.0, 2.0, 2.0, 2.0, 1.0])
    [row] = [c for c in f.linear if c.name == "phase_durations"]
    assert row.violation(x).max() < 1e-12
    durations = layout.durations(x[v.phase_scale])
    schedule = layout.schedule(durations)
    # Eq. 3: every foot's phases sum to T; a foot's swing is one global phase.
    for leg in range(6):
        assert sum(schedule.phase_durations[leg]) == pytest.approx(1.6, abs=1e-12)
    np.testing.assert_allclose(schedule.swing_intervals(0)[0], [0.2, 0.2 + durations[1]])
    np.testing.assert_allclose(schedule.swing_intervals(3)[0],
                               [0.2 + durations[1], 0.2 + durations[1] + durations[2]])


@pytest.mark.parametrize("kind", ["dynamics", "dynamics/linear", "kinematics", "force",
                                  "terrain/swing", "phase_continuity/position/velocity",
                                  "phase_continuity/rpy/velocity",
                                  "phase_continuity/position/acceleration",
                                  "phase_continuity/rpy/acceleration"])
def test_jacobians_with_duration_columns_match_finite_differences(perturbed, kind):
    f, x = perturbed
    [c] = [c for c in f.nonlinear if c.name == kind]
    _check_jacobian(c, x, f.variables.num_vars)
    if kind.startswith(("dynamics", "phase_continuity")):
        # These read the durations: their Jacobian has entries in the scale columns.
        J = c.jacobian(x, f.variables.num_vars)
        assert np.abs(J[:, f.variables.phase_scale].toarray()).max() > 1e-3


def test_realized_plan_is_the_program_in_real_time(perturbed):
    """Positions and forces at nominal time tau equal the realised plan's at t(tau); rates and
    accelerations are divided by rho and rho^2."""
    f, x = perturbed
    v, layout = f.variables, f.layout
    real, xr = realize(f, x)
    vr = real.variables
    G, Gr = layout.nominal_boundaries, vr.phase_boundaries
    tau = np.linspace(0.01, 1.59, 37)
    j = layout.phase_of(tau)
    t = Gr[j] + (tau - G[j]) * (Gr[j + 1] - Gr[j]) / (G[j + 1] - G[j])
    rho = x[v.phase_scale][j][:, None]
    for order in (0, 1, 2):
        for a, b in ((v.base_position, vr.base_position), (v.base_rpy, vr.base_rpy)):
            np.testing.assert_allclose(a.evaluate(x, tau, order) / rho ** order,
                                       b.evaluate(xr, t, order), atol=1e-9)
    for leg in range(6):
        np.testing.assert_allclose(v.foot_position[leg].evaluate(x, tau),
                                   vr.foot_position[leg].evaluate(xr, t), atol=1e-12)
        np.testing.assert_allclose(v.foot_force[leg].evaluate(x, tau),
                                   vr.foot_force[leg].evaluate(xr, t), atol=1e-12)


def test_solve_with_free_durations_holds_densely(tmp_path):
    """Flat 1 m in 2 s with free durations: solved, the durations moved within their bounds
    and sum to T per foot, and the saved .npz passes the independent checks (swing feet above
    the terrain, stance forces pushing inside the pyramid, residuals) at every 100 Hz sample."""
    solution = solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=2.0), params=PARAMS)
    assert solution.success, solution.reason
    assert solution.dense.passed
    schedule = solution.contact_schedule
    nominal = make_gait("tripod", 6, 2.0, stand_duration=0.2).phase_durations
    changed = max(abs(a - b) for d, n in zip(schedule.phase_durations, nominal)
                  for a, b in zip(d, n))
    assert changed > 1e-3  # the durations are variables, not the nominal ones
    for leg, durations in enumerate(schedule.phase_durations):
        assert sum(durations) == pytest.approx(2.0, abs=1e-9)
        for a, b in zip(durations[1:-1:2], nominal[leg][1:-1:2]):  # swings within bounds
            assert 0.5 * b - 1e-6 <= a <= 2.0 * b + 1e-6
    path = solution.save_npz(tmp_path / "plan.npz")
    data = np.load(path)
    np.testing.assert_allclose(np.nansum(data["phase_durations"], axis=1), 2.0, atol=1e-9)
    assert_plan_holds(data, "flat, free durations")


def test_bad_duration_settings_are_refused():
    with pytest.raises(QzError, match="phase_duration_bounds"):
        BlcParameters(optimize_phase_durations=True, phase_duration_bounds=(1.2, 2.0))
    with pytest.raises(QzError, match="blc.costs"):
        BlcParameters(optimize_phase_durations=True, costs=(("force_rate", 1.0),))
