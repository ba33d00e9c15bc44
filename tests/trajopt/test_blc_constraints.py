"""Every BLC constraint: a hand-checked value and its analytic sparse Jacobian against central
finite differences over the whole decision vector, at a perturbed point on uneven terrain."""

import math

import numpy as np
import pytest

from qz_drake.terrain import make_terrain
from qz_drake.trajopt import terrain as tt
from qz_drake.trajopt.constraints import (AngularDynamicsConstraint, ForceConstraint,
                                          KinematicsConstraint, TerrainConstraint,
                                          acceleration_continuity_matrix, linear_dynamics_matrix,
                                          rotation_from_rpy)
from qz_drake.trajopt.formulation import BlcFormulation
from qz_drake.trajopt.gait import make_gait
from qz_drake.trajopt.initial_guess import straight_line_guess
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import GRAVITY, qingzhui
from qz_drake.trajopt.solver import standing_start
from qz_drake.trajopt.splines import LinearSamples


def _formulation(terrain, duration=1.2, target=(0.4, 0.1, 0.3)):
    robot = qingzhui("nominal")
    params = BlcParameters()
    schedule = make_gait("tripod", robot.num_legs, duration, stand_duration=params.stand_duration)
    start, rpy, feet = standing_start(robot, terrain)
    return BlcFormulation(robot, terrain, params, schedule, start_position=start, start_rpy=rpy,
                          start_feet=feet, target=target)


@pytest.fixture(scope="module")
def rough():
    """A formulation on gridded rough ground and a point with every variable perturbed."""
    heightmap = make_terrain("rough", seed=3, amplitude=0.06, correlation_length=0.3)
    f = _formulation(tt.as_terrain(heightmap))
    x = straight_line_guess(f)
    rng = np.random.default_rng(0)
    x = x + 0.03 * rng.standard_normal(len(x))
    return f, x


def _check_jacobian(constraint, x, num_vars, step=1e-6, tol=1e-5):
    J = constraint.jacobian(x, num_vars).toarray()
    fd = np.zeros_like(J)
    for k in range(num_vars):
        e = np.zeros(num_vars)
        e[k] = step
        fd[:, k] = (constraint.evaluate(x + e) - constraint.evaluate(x - e)) / (2 * step)
    scale = max(1.0, np.abs(fd).max())
    np.testing.assert_allclose(J, fd, atol=tol * scale, rtol=0)
    # The declared pattern covers every non-zero of the true Jacobian.
    declared = np.zeros_like(J, dtype=bool)
    declared[constraint.rows, constraint.cols] = True
    assert not np.any((np.abs(fd) > 1e-7 * scale) & ~declared)


@pytest.mark.parametrize("kind", ["dynamics", "kinematics", "terrain/stance", "terrain/swing",
                                  "swing/apex", "force"])
def test_nonlinear_constraint_jacobian_matches_finite_differences(rough, kind):
    f, x = rough
    [c] = [c for c in f.nonlinear if c.name == kind]
    _check_jacobian(c, x, f.variables.num_vars)


def test_linear_constraints_match_their_definition(rough):
    """The linear dynamics rows are r''/g - sum F + e_z; the continuity rows vanish on a spline
    with one cubic through all nodes (continuous acceleration)."""
    f, x = rough
    v = f.variables
    t = f.dynamics_times
    A, b = linear_dynamics_matrix(v, t, GRAVITY)
    acc = v.base_position.evaluate(x, t, 2)
    forces = sum(v.foot_force[leg].evaluate(x, t, 0) for leg in range(v.num_legs))
    np.testing.assert_allclose((A @ x - b).reshape(-1, 3), acc / GRAVITY - forces
                               + np.array([0, 0, 1.0]), atol=1e-12)
    C = acceleration_continuity_matrix(v)
    assert C.shape[0] == 6 * (len(v.base_breaks) - 2)
    # Nodes sampled from one cubic: accelerations are continuous, so C x = 0.
    y = np.zeros(v.num_vars)
    tb = v.base_breaks
    for idx in (v.base_lin, v.base_ang):
        y[idx[:, 0]] = np.column_stack([tb ** 3, 2 * tb ** 3 - tb, tb ** 2])
        y[idx[:, 1]] = np.column_stack([3 * tb ** 2, 6 * tb ** 2 - 1, 2 * tb])
    np.testing.assert_allclose(C @ y, 0.0, atol=1e-10)
    y[v.base_lin[3, 0, 0]] += 0.01  # a kink
    assert np.abs(C @ y).max() > 1e-3


def _single(values):
    """LinearSamples reading variables 0..n-1 directly: sample k, component d = x[k*D + d]."""
    values = np.atleast_2d(values)
    n, D = values.shape
    return LinearSamples(np.ones((n, 1, D)), np.arange(n * D).reshape(n, 1, D)), values.reshape(-1)


def test_terrain_constraint_hand_checked_on_a_slope():
    slope = tt.SlopeTerrain(angle_deg=20.0, start_x=0.0, edge_width=0.01)
    samples, x = _single([[1.0, 0.3, 0.5], [-1.0, 0.0, 0.05]])
    c = TerrainConstraint(samples, slope, 0.03, 0.0, 0.0)
    h = math.tan(math.radians(20.0)) * 1.0
    np.testing.assert_allclose(c.evaluate(x), [0.5 - h - 0.03, 0.05 - 0.0 - 0.03], atol=1e-9)
    np.testing.assert_allclose(c.violation(x), np.abs(c.evaluate(x)), atol=1e-12)
    _check_jacobian(c, x, len(x))


def test_force_constraint_hand_checked_and_in_the_terrain_frame():
    mu = 0.5
    forces, fx = _single([[0.1, 0.0, 1.0], [0.0, 0.0, 1.0]])
    holds = LinearSamples(np.ones((2, 1, 3)), np.arange(6, 12).reshape(2, 1, 3))
    x = np.concatenate([fx, [0.2, 0.0, 0.0, 1.0, 0.0, 0.36]])
    flat = ForceConstraint(forces, holds, tt.FlatTerrain(), mu, 0.01, 2.0)
    g = flat.evaluate(x).reshape(2, 5)
    # Rows: normal, +-t1 - mu n, +-t2 - mu n.
    np.testing.assert_allclose(g[0], [1.0, 0.1 - mu, -0.1 - mu, -mu, -mu], atol=1e-12)
    assert np.all(flat.violation(x) == 0)
    # On a 30 deg slope (rising along x, t1 = (cos 30, 0, sin 30)) a vertical force has normal
    # part cos 30 and tangential part F.t1 = sin 30: it needs mu >= tan 30 = 0.577.
    slope = tt.SlopeTerrain(angle_deg=30.0, start_x=-5.0, edge_width=0.01)
    c = ForceConstraint(forces, holds, slope, mu, 0.01, 2.0)
    g = c.evaluate(x).reshape(2, 5)
    a = math.radians(30.0)
    np.testing.assert_allclose(g[1, 0], math.cos(a), atol=1e-9)
    np.testing.assert_allclose(g[1, 1:3], [math.sin(a) - mu * math.cos(a), -math.sin(a) - mu * math.cos(a)],
                               atol=1e-9)
    assert c.violation(x).reshape(2, 5)[1, 1] > 0.05
    _check_jacobian(c, x, len(x))


def test_kinematics_constraint_hand_checked_in_the_body_frame():
    robot = qingzhui("nominal")
    f = _formulation(tt.FlatTerrain())
    c = KinematicsConstraint(f.variables, [0.0], robot.nominal_footholds, robot.box_half_sizes)
    x = np.zeros(f.variables.num_vars)
    v = f.variables
    r = np.array([0.2, -0.1, 0.5])
    yaw = math.pi / 2
    x[v.base_lin[0, 0]] = r
    x[v.base_ang[0, 0]] = [0.0, 0.0, yaw]
    R = rotation_from_rpy(np.array([[0.0, 0.0, yaw]]))[0]
    offsets = np.array([0.05, -0.02, 0.01])
    for leg in range(v.num_legs):
        x[v.footholds[leg][0]] = r + R @ (robot.nominal_footholds[leg] + offsets * (leg + 1))
    g = c.evaluate(x).reshape(v.num_legs, 3)
    np.testing.assert_allclose(g, offsets[None] * np.arange(1, 7)[:, None], atol=1e-12)
    # Legs 3..5 leave the 0.10 m z range (0.04, 0.05, 0.06 are inside; x 0.15 / 0.2 / 0.25 vs 0.15).
    viol = c.violation(x).reshape(v.num_legs, 3)
    np.testing.assert_allclose(viol[:, 0], np.maximum(0, 0.05 * np.arange(1, 7) - 0.15), atol=1e-12)


def test_angular_dynamics_hand_checked_static_torque():
    """At rest with one leg pushing 1 body weight straight up at a lever of (0.5, 0, -0.5) m the
    torque is lever x F = (0, -0.5, 0) and the residual -R^T (lever x F) = (0, 0.5, 0) (metres,
    since forces are in body weights): the body would pitch nose-up, which nothing balances."""
    robot = qingzhui("nominal")
    f = _formulation(tt.FlatTerrain())
    v = f.variables
    t = 0.05  # in the initial stand: all feet in contact
    c = AngularDynamicsConstraint(v, [t], robot.inertia_matrix / robot.weight)
    x = np.zeros(v.num_vars)
    x[v.base_lin[:, 0]] = [0.0, 0.0, 0.5]
    for leg in range(v.num_legs):
        x[v.footholds[leg][0]] = [0.5, 0.0, 0.0]
    nodes = v.force_nodes[0]
    x[nodes[nodes[:, 0, 0] >= 0, 0, 2]] = 1.0  # leg 0 pushes one body weight up
    np.testing.assert_allclose(c.evaluate(x), [0.0, 0.5, 0.0], atol=1e-12)
    # Spinning about z at a constant 1 rad/s with no torque: Euler's equation holds (w x Iw = 0
    # for a principal axis).
    x[nodes[:, 0, 2][nodes[:, 0, 2] >= 0]] = 0.0
    x[v.base_ang[:, 0, 2]] = v.base_breaks
    x[v.base_ang[:, 1, 2]] = 1.0
    np.testing.assert_allclose(c.evaluate(x), 0.0, atol=1e-12)


def test_terrain_models_have_exact_derivatives():
    heightmap = make_terrain("rough", seed=1, amplitude=0.08, correlation_length=0.25)
    terrains = [tt.as_terrain(heightmap), tt.stairs(), tt.gap(), tt.block(), tt.slope()]
    rng = np.random.default_rng(2)
    x = rng.uniform(-1.0, 2.5, 200)
    y = rng.uniform(-1.0, 1.0, 200)
    eps = 1e-6
    for terrain in terrains:
        h, hx, hy, hxx, hxy, hyy = terrain.height_derivatives(x, y)
        # height() is the same function, to the last bit (the guess and the dense verdict use
        # it, the constraints the derivatives).
        np.testing.assert_array_equal(terrain.height(x, y), h, err_msg=terrain.name)
        for d, (dx, dy) in ((hx, (eps, 0)), (hy, (0, eps))):
            fd = (terrain.height(x + dx, y + dy) - terrain.height(x - dx, y - dy)) / (2 * eps)
            np.testing.assert_allclose(d, fd, atol=1e-5, err_msg=terrain.name)
        gx = lambda a, b: terrain.height_derivatives(a, b)[1]  # noqa: E731
        gy = lambda a, b: terrain.height_derivatives(a, b)[2]  # noqa: E731
        np.testing.assert_allclose(hxx, (gx(x + eps, y) - gx(x - eps, y)) / (2 * eps), atol=1e-3,
                                   err_msg=terrain.name)
        np.testing.assert_allclose(hxy, (gx(x, y + eps) - gx(x, y - eps)) / (2 * eps), atol=1e-3,
                                   err_msg=terrain.name)
        np.testing.assert_allclose(hyy, (gy(x, y + eps) - gy(x, y - eps)) / (2 * eps), atol=1e-3,
                                   err_msg=terrain.name)
    # The grid interpolant passes through the map's nodes.
    g = tt.as_terrain(heightmap)
    iy, ix = 17, 23
    xs = heightmap.origin[0] + ix * heightmap.resolution
    ys = heightmap.origin[1] + iy * heightmap.resolution
    assert g.height(xs, ys) == pytest.approx(heightmap.heights[iy, ix], abs=1e-12)


def test_formulation_bounds_fix_start_and_goal():
    f = _formulation(tt.FlatTerrain(), target=(0.5, 0.2, 0.4))
    v = f.variables
    assert np.all(f.lower[v.base_lin[0, 0]] == f.start_position)
    assert np.all(f.upper[v.base_lin[-1, 0, :2]] == [0.5, 0.2])
    assert f.lower[v.base_ang[-1, 0, 2]] == pytest.approx(0.4)
    assert np.all(f.lower[v.base_lin[-1, 1]] == 0) and np.all(f.upper[v.base_ang[-1, 1]] == 0)
    for leg in range(v.num_legs):
        np.testing.assert_array_equal(f.lower[v.footholds[leg][0]], f.start_feet[leg])
    # A target yaw a full turn away is the same heading: the body turns the short way round.
    g = _formulation(tt.FlatTerrain(), target=(0.5, 0.2, 0.4 + 2 * math.pi))
    assert g.target_yaw == pytest.approx(0.4)
