"""Legs clear of the terrain in the BLC (issue 34; paper 000 Fig. 2): the links' points from the
legs' inverse kinematics, the clearance field, the constraint's Jacobian, the guess, the dense
verdict, and Fig. 2 itself on a 0.2 m step."""

import numpy as np
import pytest

from qz_drake.config import TerrainConfig
from qz_drake.errors import ConfigError
from qz_drake.robot import kinematics
from qz_drake.robot.params import DEFAULT_PARAMS
from qz_drake.robot.topology import TOPOLOGY_NAMES, get_topology
from qz_drake.station import make_heightmap
from qz_drake.trajopt.constraints import rotation_from_rpy
from qz_drake.trajopt.formulation import BlcFormulation
from qz_drake.trajopt.gait import make_gait
from qz_drake.trajopt.initial_guess import straight_line_guess
from qz_drake.trajopt.leg_clearance import (LegClearanceConstraint, clearance_field, dense_link_check,
                                            field_from_grid, raw_ground)
from qz_drake.trajopt.legs import LinkPoints, link_geometry, link_points
from qz_drake.trajopt.parameters import DEFAULT_CONSTRAINTS, BlcParameters
from qz_drake.trajopt.robot_model import hyq, qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc, standing_start
from qz_drake.trajopt.terrain import as_terrain
from qz_drake.trajopt.verdict import dense_check
from tests.trajopt.test_blc_constraints import _check_jacobian

RISE = 0.2  # [m]


def _random_poses(robot, n=5, seed=0):
    rng = np.random.default_rng(seed)
    rpy = rng.normal(0.0, 0.1, (n, 3))
    com = rng.normal(0.0, 0.1, (n, 3)) + [0.0, 0.0, 0.5]
    feet_B = robot.nominal_footholds[None] + rng.uniform(-1, 1, (n, 6, 3)) * robot.box_half_sizes[None] * 0.8
    feet = com[:, None, :] + np.einsum("nij,nlj->nli", rotation_from_rpy(rpy), feet_B)
    return com, rpy, feet, feet_B


@pytest.mark.parametrize("topology", TOPOLOGY_NAMES)
def test_knees_are_those_of_the_legs_inverse_kinematics(topology):
    """The knee from the body pose and the foot is paper 002's IK knee of that topology's bend,
    for random poses and feet anywhere in the kinematic boxes."""
    robot = qingzhui(topology)
    com, rpy, feet, feet_B = _random_poses(robot)
    points = LinkPoints.along((DEFAULT_PARAMS.thigh_length,), ())
    knee, _ = link_points(link_geometry(robot), points, com, rpy, feet, with_gradient=False)
    q, ok = kinematics.all_legs_inverse_kinematics(feet_B + np.array(robot.com_B), get_topology(topology).bends)
    assert ok.all()
    m = kinematics.urdf_to_motor(q)
    l1 = DEFAULT_PARAMS.thigh_length
    knee_L = np.stack([l1 * np.cos(m[..., 1]), l1 * np.sin(m[..., 1]) * np.cos(m[..., 0]),
                       l1 * np.sin(m[..., 1]) * np.sin(m[..., 0])], -1)
    knee_B = (np.einsum("lij,nlj->nli", kinematics.all_leg_rotations(), knee_L)
              + np.array(DEFAULT_PARAMS.hip_positions) - np.array(robot.com_B))
    knee_W = com[:, None, :] + np.einsum("nij,nlj->nli", rotation_from_rpy(rpy), knee_B)
    np.testing.assert_allclose(knee[:, :, 0], knee_W, atol=1e-12)
    # Knee out: radially outside the hip-foot line (in the leg plane, x radial, "down" the
    # planar distance); in: inside.
    foot_L = kinematics.foot_position_leg_frame(m)
    side = (knee_L[..., 0] * np.hypot(foot_L[..., 1], foot_L[..., 2])
            - np.hypot(knee_L[..., 1], knee_L[..., 2]) * foot_L[..., 0])
    np.testing.assert_array_equal(np.sign(side), np.broadcast_to(get_topology(topology).bends, side.shape))


def test_link_point_gradients_match_finite_differences():
    robot = qingzhui("hind_bend")
    com, rpy, feet, _ = _random_poses(robot, seed=1)
    geometry = link_geometry(robot)
    points = LinkPoints.along((0.1, 0.36), (0.05, 0.2, 0.4))
    _, grad = link_points(geometry, points, com, rpy, feet)
    step = 1e-6
    for k in range(9):
        def at(delta):
            c, r, f = com.copy(), rpy.copy(), feet.copy()
            if k < 3:
                c[:, k] += delta
            elif k < 6:
                r[:, k - 3] += delta
            else:
                f[..., k - 6] += delta
            return link_points(geometry, points, c, r, f, with_gradient=False)[0]
        fd = (at(step) - at(-step)) / (2 * step)
        np.testing.assert_allclose(grad[..., k], fd, atol=1e-8)


def _step_map(rise=RISE, start_x=1.0):
    return make_heightmap(TerrainConfig(kind="step", params=dict(height=rise, start_x=start_x)))


def test_the_clearance_field_is_at_least_the_highest_ground_near_each_point():
    """Conservative along a straight edge: at any point the interpolated field is at least the
    highest raw cell that a disc of the footprint overlaps (with and without smoothing), and
    it equals the ground far from edges."""
    heightmap = _step_map()
    terrain = as_terrain(heightmap)
    footprint = 0.055
    rng = np.random.default_rng(0)
    x = rng.uniform(0.5, 1.5, 4000)
    y = rng.uniform(-0.5, 0.5, 4000)
    ground = raw_ground(terrain)
    angles = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    highest = np.max([ground(x + r * np.cos(a), y + r * np.sin(a))
                      for r in (0.0, 0.5 * footprint, footprint) for a in angles], axis=0)
    far = np.abs(x - 1.0) > footprint + 0.2
    for smoothing in (0.0, 0.05):
        field = field_from_grid(terrain.heights, terrain.resolution, terrain.origin, footprint, 0.05, smoothing)
        assert np.all(field.surface.height(x, y) >= highest - 1e-9)
        np.testing.assert_allclose(field.surface.height(x[far], y[far]), ground(x[far], y[far]), atol=1e-9)


def test_the_field_exists_only_where_the_ground_has_relief():
    """No rows where nothing is in reach: flat ground, a gentle slope, or a region away from
    the step."""
    params = BlcParameters()
    for kind, extra in (("flat", {}), ("slope", dict(angle_deg=15.0, start_x=0.5))):
        terrain = as_terrain(make_heightmap(TerrainConfig(kind=kind, params=extra)))
        assert clearance_field(terrain, 0.055, params.leg_clearance_relief, (-1, 2, -1, 1)) is None
    terrain = as_terrain(_step_map(start_x=3.0))
    assert clearance_field(terrain, 0.055, params.leg_clearance_relief, (-1, 2, -1, 1)) is None
    assert clearance_field(terrain, 0.055, params.leg_clearance_relief, (-1, 3.5, -1, 1)) is not None


def _formulation(topology, terrain, target=(0.3, 0.0, 0.0), duration=1.6, start_x=0.0, params=None):
    robot = qingzhui(topology)
    params = BlcParameters() if params is None else params
    schedule = make_gait("tripod", robot.num_legs, duration, stand_duration=params.stand_duration)
    start, rpy, feet = standing_start(robot, terrain, x=start_x)
    return BlcFormulation(robot, terrain, params, schedule, start_position=start, start_rpy=rpy,
                          start_feet=feet, target=(start_x + target[0], target[1], target[2]))


# A row per link point (leg_clearance_softmin None, the default).
POINT_ROWS = BlcParameters(leg_clearance_softmin=None)


def test_the_constraint_jacobian_matches_finite_differences():
    terrain = as_terrain(_step_map(start_x=1.0))
    f = _formulation("nominal", terrain, start_x=0.15, params=POINT_ROWS)
    [c] = [c for c in f.nonlinear if c.name == "leg_clearance"]
    x = straight_line_guess(f) + 0.02 * np.random.default_rng(0).standard_normal(f.variables.num_vars)
    # Points near the step's ramp in the field (where its slope matters) are among the rows.
    g = c.evaluate(x)
    assert np.any(g < 0.25)
    _check_jacobian(c, x, f.variables.num_vars)


def test_the_smooth_minimum_holds_a_leg_only_where_all_its_points_hold():
    """One row per sample and leg (leg_clearance_softmin): its Jacobian matches finite
    differences, and its value lies between the least point clearance less log(J) / rho and
    that least clearance, so a row that holds keeps every point of the leg above its bound."""
    terrain = as_terrain(_step_map(start_x=1.0))
    points = _formulation("nominal", terrain, start_x=0.15, params=POINT_ROWS)
    rho = 300.0
    smooth = _formulation("nominal", terrain, start_x=0.15, params=BlcParameters(leg_clearance_softmin=rho))
    [c] = [c for c in smooth.nonlinear if c.name == "leg_clearance"]
    [each] = [c for c in points.nonlinear if c.name == "leg_clearance"]
    n, L, J = len(c.times), c.num_legs, c.num_points
    assert c.num_constraints == n * L and each.num_constraints == n * L * J
    assert len(c.rows) * J == len(each.rows)  # J times fewer Jacobian entries
    # Both carry the same per-point bounds (the start's relaxation included).
    np.testing.assert_array_equal(c.point_lower, each.lower)
    np.testing.assert_array_equal(c.lower, 0.0)
    x = straight_line_guess(smooth) + 0.02 * np.random.default_rng(0).standard_normal(smooth.variables.num_vars)
    _check_jacobian(c, x, smooth.variables.num_vars)
    least = (each.evaluate(x) - each.lower).reshape(n, L, J).min(axis=2).reshape(-1)
    s = c.evaluate(x)
    assert np.all(s <= least + 1e-12)
    assert np.all(s >= least - np.log(J) / rho - 1e-12)
    assert np.any(least < 0.05)  # some points near the step
    # The mean form: the same function, its bound log(J) / rho lower.
    mean = _formulation("nominal", terrain, start_x=0.15,
                        params=BlcParameters(leg_clearance_softmin=rho, leg_clearance_softmin_mean=True))
    [m] = [c for c in mean.nonlinear if c.name == "leg_clearance"]
    np.testing.assert_array_equal(m.evaluate(x), s)
    np.testing.assert_allclose(m.lower, -np.log(J) / rho)


@pytest.mark.parametrize("value", [0.0, -5.0, float("inf"), float("nan"), True])
def test_a_bad_smooth_minimum_sharpness_is_refused_naming_it(value):
    with pytest.raises(ConfigError, match="blc.leg_clearance_softmin"):
        BlcParameters(leg_clearance_softmin=value)
    with pytest.raises(ConfigError, match="blc.leg_clearance_softmin_mean"):
        BlcParameters(leg_clearance_softmin_mean="yes")


def test_no_leg_rows_for_a_robot_without_modelled_legs_or_on_flat_ground():
    terrain = as_terrain(_step_map(start_x=1.0))
    robot = hyq()
    params = BlcParameters()
    schedule = make_gait("trot", robot.num_legs, 1.6, stand_duration=params.stand_duration)
    start, rpy, feet = standing_start(robot, terrain, x=0.3)
    f = BlcFormulation(robot, terrain, params, schedule, start_position=start, start_rpy=rpy,
                       start_feet=feet, target=(0.6, 0.0, 0.0))
    assert "leg_clearance" not in [c.name for c in f.nonlinear]
    flat = _formulation("nominal", as_terrain(None))
    assert "leg_clearance" not in [c.name for c in flat.nonlinear]


def _towards_the_riser(topology, gap):
    """Qingzhui standing with its MF foot ``gap`` before a 0.2 m step's riser, asked to move
    its body 0.3 m forward in 1.6 s: the MF foot's next nominal foothold is at the riser
    (paper 000 Fig. 2)."""
    robot = qingzhui(topology)
    heightmap = _step_map(start_x=robot.nominal_footholds[0, 0] + gap)
    return robot, heightmap, BlcTask(target=(0.3, 0.0, 0.0), duration=1.6, topology=topology)


def test_fig2_knee_out_shank_meets_the_riser_knee_in_does_not():
    """Paper 000 Fig. 2 on a 0.2 m step. Standing with the MF foot 5 cm before the riser, the
    nominal topology's knee-out shank leans on the riser's nose and front_bend's knee-in shank
    is clear. Walking up to the riser, nominal's plan keeps every link clear or fails
    honestly; front_bend's plan is clear."""
    params = BlcParameters(time_limit=60.0)
    for topology, touches in (("nominal", True), ("front_bend", False)):
        robot, heightmap, _ = _towards_the_riser(topology, 0.05)
        terrain = as_terrain(heightmap)
        start, rpy, feet = standing_start(robot, terrain)
        check = dense_link_check(robot, terrain, np.zeros(1), start[None], rpy[None], feet[None])
        assert (check.min_clearance < 0) == touches, topology
        if touches:
            assert check.worst[0] == 0 and check.worst[1].startswith("shank")  # MF's shank
    for topology in ("nominal", "front_bend"):
        _, heightmap, task = _towards_the_riser(topology, 0.2)
        solution = solve_blc(task, terrain=heightmap, params=params)
        if topology == "front_bend":
            assert solution.success, solution.reason
        if solution.success:
            assert solution.dense.min_link_clearance >= -params.dense_link_tolerance, topology
        else:
            assert solution.reason


def test_the_dense_verdict_fails_a_plan_whose_shank_passes_through_the_riser():
    """The plan of the BLC without the leg constraint on the Fig. 5 stairs (0.2 m, 1.5 m):
    every sampled constraint holds and the feet are clear, but the MF shank passes through
    the second riser; the dense check fails it, naming the leg, the link, the depth and the
    time."""
    heightmap = make_heightmap(TerrainConfig(kind="stairs", params=dict(rise=0.2, run=0.4, count=2,
                                                                        start_x=1.25)))
    without = tuple(c for c in DEFAULT_CONSTRAINTS if c != "leg_clearance")
    task = BlcTask(target=(1.5, 0.0, 0.0), duration=4.0)
    solution = solve_blc(task, terrain=heightmap, params=BlcParameters(constraints=without, time_limit=60.0))
    assert solution.max_violation <= 1e-3
    assert solution.dense.min_swing_clearance >= -2e-3
    assert not solution.success
    [failure] = [f for f in solution.dense.failures if "into the ground" in f]
    assert failure.startswith("MF leg (shank") and " m into the ground at t = " in failure
    assert solution.dense.min_link_clearance < -0.02
    # With the constraint the same task is planned with the legs clear.
    clear = solve_blc(task, terrain=heightmap, params=BlcParameters(time_limit=60.0))
    assert clear.success, clear.reason
    assert clear.dense.min_link_clearance >= -BlcParameters().dense_link_tolerance


def test_the_guess_steps_back_from_a_riser_the_shank_would_lean_on():
    """With the MF foot's stance window ending just before a 0.2 m riser, the straight-line
    guess keeps every link above the field at the stance's ends (it used to stand the foot
    at the riser's foot, the knee-out shank on the nose)."""
    terrain = as_terrain(_step_map(start_x=1.05))
    f = _formulation("nominal", terrain, target=(0.3, 0.0, 0.0), duration=1.6)
    [c] = [c for c in f.nonlinear if c.name == "leg_clearance"]
    x0 = straight_line_guess(f)
    holds = x0[f.variables.footholds[0]].reshape(-1, 3)
    lc = f.link_clearance()
    for k, (t0, t1) in enumerate(f.variables.schedule.stance_intervals(0)):
        for t in (t0, t1):
            com = f.variables.base_position.sample(np.array([t]), 0).value(x0)[0]
            rpy = f.variables.base_rpy.sample(np.array([t]), 0).value(x0)[0]
            assert lc.depth(0, com, rpy, holds[k:k + 1])[0] == pytest.approx(0.0, abs=1e-9), (k, t)
    assert c.violation(x0).max() < 0.02
