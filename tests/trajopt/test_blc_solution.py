"""A solved BLC trajectory keeps its promises, checked from the saved .npz alone (paper 000
Eq. 1-6): goal, single-rigid-body dynamics, stance feet immobile and on the ground, swing feet
above it and unloaded, forces inside the friction pyramid of the terrain's own normal. Plus the
verdicts: an impossible task is a failed result within the time limit; bad input is a QzError."""

import math
import time

import numpy as np
import pytest

from qz_drake.errors import QzError
from qz_drake.robot.params import DEFAULT_PARAMS
from qz_drake.terrain import make_terrain
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc
from tests.trajopt.npz_checks import assert_plan_holds, bilinear, body_rate, rotation

SLOPE_DEG = 10.0


@pytest.fixture(scope="module")
def uphill(tmp_path_factory):
    """1 m up a uniform 10 deg incline (the whole map rises along +x) in 2.5 s, saved."""
    heightmap = make_terrain("slope", angle_deg=SLOPE_DEG, start_x=-2.0)
    # The tests check plans, not speed: a loaded machine must not fail them on the time limit.
    solution = solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=2.5), qingzhui(), heightmap,
                         BlcParameters(time_limit=60.0))
    path = solution.save_npz(tmp_path_factory.mktemp("blc") / "uphill.npz")
    return solution, dict(np.load(path))


def _bilinear_height_and_gradient(data, x, y):
    """Height and its gradient from the saved map (bilinear; exact on a uniform incline)."""
    return bilinear(data, x, y)[:3]


def test_solved_uphill_walk_reaches_the_goal(uphill):
    solution, data = uphill
    assert solution.success, solution.reason
    assert solution.max_violation < 1e-3
    np.testing.assert_allclose(data["base_pos"][-1, :2], [1.0, 0.0], atol=1e-3)
    assert data["t"][-1] == pytest.approx(2.5)
    assert np.allclose(np.diff(data["t"]), 0.01)
    # The body rose with the ground: about tan(10 deg) per metre.
    rise = data["base_pos"][-1, 2] - data["base_pos"][0, 2]
    assert rise == pytest.approx(math.tan(math.radians(SLOPE_DEG)), abs=0.05)


def test_saved_samples_satisfy_single_rigid_body_dynamics(uphill):
    """m (a - g) = sum f at the linear-dynamics samples and I w' + w x I w = R^T sum (p - r) x f
    at the angular ones (interval midpoints of BlcParameters' spacings), derivatives by central
    differences of the 100 Hz samples."""
    _, data = uphill
    t, r, rpy = data["t"], data["base_pos"], data["base_rpy"]
    m, inertia, gravity = float(data["mass"]), data["inertia"], data["gravity"]
    weight = m * 9.81
    dt = t[1] - t[0]
    params = BlcParameters()
    worst_linear = worst_angular = 0.0
    def linear_residual(k):
        acc = (r[k + 1] - 2 * r[k] + r[k - 1]) / dt ** 2
        return m * (acc - gravity) - data["foot_force"][k].sum(axis=0)

    checked = 0
    for ts in np.arange(0.5 * params.linear_dynamics_dt, t[-1], params.linear_dynamics_dt):
        # The samples fall between the 100 Hz grid points: interpolate the residual (a cubic in
        # time) from its two neighbours, unless a contact switch lies between them.
        k = int(np.floor(ts / dt + 1e-9))
        if np.any(data["contact"][k] != data["contact"][k + 1]):
            continue
        s = (ts - t[k]) / dt
        residual = (1 - s) * linear_residual(k) + s * linear_residual(k + 1)
        worst_linear = max(worst_linear, np.abs(residual).max() / weight)
        checked += 1
    assert checked > 0.8 * t[-1] / params.linear_dynamics_dt
    def angular_residual(k):
        f, p = data["foot_force"][k], data["foot_pos"][k]
        w = [body_rate(rpy[j], (rpy[j + 1] - rpy[j - 1]) / (2 * dt)) for j in (k - 1, k, k + 1)]
        w_dot = (w[2] - w[0]) / (2 * dt)
        torque_W = np.cross(p - r[k], f).sum(axis=0)
        return inertia @ w_dot + np.cross(w[1], inertia @ w[1]) - rotation(rpy[k]).T @ torque_W

    for ts in np.arange(0.5 * params.dynamics_dt, t[-1], params.dynamics_dt):
        k = int(np.floor(ts / dt + 1e-9))
        if np.any(data["contact"][k] != data["contact"][k + 1]):
            continue
        s = (ts - t[k]) / dt
        residual = (1 - s) * angular_residual(k) + s * angular_residual(k + 1)
        worst_angular = max(worst_angular, np.abs(residual).max() / weight)
    # Body weights; the interpolation between grid points adds up to about 2e-3 where the
    # forces bend fastest.
    assert worst_linear < 5e-3
    assert worst_angular < 2e-3  # metres (torque / m g)


def test_stance_feet_are_immobile_on_the_ground_and_swing_feet_above_it(uphill):
    _, data = uphill
    feet, contact, force = data["foot_pos"], data["contact"], data["foot_force"]
    radius = DEFAULT_PARAMS.foot_radius
    h, _, _ = _bilinear_height_and_gradient(data, feet[..., 0], feet[..., 1])
    clearance = feet[..., 2] - h - radius
    assert np.abs(clearance[contact]).max() < 2e-3
    assert clearance[~contact].min() > -5e-3
    assert clearance[~contact].max() > 0.05  # the swing apex
    still = contact[1:] & contact[:-1]
    moved = np.linalg.norm(np.diff(feet, axis=0), axis=-1)
    assert moved[still].max() < 1e-9
    assert np.abs(force[~contact]).max() < 1e-9
    # Every foot took steps (a tripod: the slope is climbed, not slid up).
    assert all((~contact[:, leg]).any() for leg in range(contact.shape[1]))


def test_stance_forces_lie_in_the_friction_pyramid_of_the_terrain_normal(uphill):
    _, data = uphill
    feet, contact, force = data["foot_pos"], data["contact"], data["foot_force"]
    mu = float(data["mu"])
    weight = float(data["mass"]) * 9.81
    _, hx, hy = _bilinear_height_and_gradient(data, feet[..., 0], feet[..., 1])
    n = np.stack([-hx, -hy, np.ones_like(hx)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    t1 = np.stack([np.ones_like(hx), np.zeros_like(hx), hx], -1)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.stack([np.zeros_like(hx), np.ones_like(hx), hy], -1)
    t2 /= np.linalg.norm(t2, axis=-1, keepdims=True)
    fn = (force * n).sum(-1)[contact]
    f1 = (force * t1).sum(-1)[contact]
    f2 = (force * t2).sum(-1)[contact]
    tol = 2e-3 * weight
    assert fn.min() > BlcParameters().min_normal_force - tol
    assert np.all(np.abs(f1) <= mu * fn + tol)
    assert np.all(np.abs(f2) <= mu * fn + tol)
    # In world axes the pyramid would be the wrong test: holding still on 10 deg needs a
    # tangential push along the slope of about sin(10 deg) of the weight.
    assert np.abs(f1).max() > 0.1 * mu * fn.max()


def test_uphill_plan_holds_between_samples(uphill):
    """Issue 11's dense figures, from the .npz alone (npz_checks.py)."""
    solution, data = uphill
    assert solution.dense.passed, solution.dense.failures
    assert_plan_holds(data, "uphill")


def test_feet_stay_in_their_kinematic_boxes(uphill):
    _, data = uphill
    robot = qingzhui()
    for k in range(0, len(data["t"]), 4):  # the 0.04 s samples
        R = rotation(data["base_rpy"][k])
        local = (data["foot_pos"][k] - data["base_pos"][k]) @ R - robot.nominal_footholds
        assert np.all(np.abs(local) <= robot.box_half_sizes + 1e-3), data["t"][k]


def test_impossible_tasks_fail_with_a_reason_within_the_time_limit():
    params = BlcParameters(time_limit=2.0)
    clock = time.perf_counter()
    far = solve_blc(BlcTask(target=(5.0, 0.0, 0.0), duration=1.0), params=params)
    assert time.perf_counter() - clock < 2.0 + 0.5  # the call, not a timing claim: no hang
    assert not far.success and far.reason
    wall = make_terrain("step", height=1.0, start_x=1.0)
    blocked = solve_blc(BlcTask(target=(1.5, 0.0, 0.0), duration=3.0), terrain=wall, params=params)
    assert not blocked.success and "violation" in blocked.reason


def test_a_target_beyond_the_boxes_reach_fails_before_ipopt():
    """Qingzhui's tripod over 1 s: two overlapping stances cover it (group B until 0.5 s,
    group A from 0.5 s); over each the body stays within rho = |(|n| + b)| of a fixed foot,
    rho = |(0.37 + 0.15, 0.553 + 0.12, 0.499 + 0.10)| = 1.04 m for the corner feet (1.09 m
    for MF and MB), plus 0.01 m, so at most 2 x 2 x 1.05 = 4.2 m."""
    from qz_drake.trajopt.gait import make_gait
    from qz_drake.trajopt.solver import reachable_distance

    robot = qingzhui()
    n = np.abs(robot.nominal_footholds) + robot.box_half_sizes
    rho = np.linalg.norm(n, axis=1) + 0.01
    schedule = make_gait("tripod", 6, 1.0)
    # Group B (MB, RF, LF) stands until 0.5 s, group A (MF, RB, LB) from 0.5 s: the cheapest
    # chain takes the least rho of each group.
    assert reachable_distance(robot, schedule) == pytest.approx(
        2 * rho[[3, 1, 5]].min() + 2 * rho[[0, 2, 4]].min())
    assert reachable_distance(robot, schedule) == pytest.approx(4.2, abs=0.01)
    far = solve_blc(BlcTask(target=(5.0, 0.0, 0.0), duration=1.0))
    assert not far.success and far.reason.startswith("infeasible: target 5.00 m away")
    assert far.iterations == 0 and far.ipopt_time == 0.0
    # Within reach, the bound stays out of the way (the solve itself decides).
    assert reachable_distance(robot, make_gait("tripod", 6, 2.0)) > 4.0


def test_bad_tasks_raise_errors_naming_the_field():
    with pytest.raises(QzError, match="task.target"):
        solve_blc(BlcTask(target=(float("nan"), 0.0, 0.0), duration=2.0))
    with pytest.raises(QzError, match="task.start_feet"):
        solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=2.0, start_feet=np.zeros((4, 3))))
    with pytest.raises(QzError, match="duration"):
        solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=0.3))
    with pytest.raises(QzError, match="gait"):
        solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=2.0, gait="trot"))
