"""The canonical terminal stance (trajopt/stance.py, BlcParameters.terminal_stance; issue 54):
the rule on a synthetic map, a BLC mission that ends in it, and the capability map asking
about the same stance the BLC ends in."""

import math

import numpy as np
import pytest

from qz_drake.capability import patches as P
from qz_drake.errors import QzError
from qz_drake.robot.params import DEFAULT_PARAMS
from qz_drake.robot.topology import get_topology
from qz_drake.terrain.heightmap import HeightMap
from qz_drake.trajopt.formulation import BlcFormulation
from qz_drake.trajopt.gait import make_gait
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc, standing_start
from qz_drake.trajopt.stance import canonical_stance
from qz_drake.trajopt.support import support_field
from qz_drake.trajopt.terrain import as_terrain

RES = 0.05
TOL = BlcParameters().terminal_foothold_tolerance


def _map(step_x=None, ramp=None, rise=0.1, size=5.0):
    """Flat ground with a step up of ``rise`` from step_x on, or a ramp of slope 1.5 (56 degrees)
    up from x0 to x1 (ramp = (x0, x1); level beyond), across the whole map (edges on cell
    boundaries)."""
    n = int(round(size / RES))
    origin = (-size / 2 + RES / 2, -size / 2 + RES / 2)
    xs = origin[0] + RES * np.arange(n)
    heights = np.zeros((n, n))
    if step_x is not None:
        heights[:, xs >= step_x] = rise
    if ramp is not None:
        heights[:] = 1.5 * np.clip(xs - ramp[0], 0.0, ramp[1] - ramp[0])
    return HeightMap(heights, RES, origin)


def _stance(heightmap, x, y=0.0, yaw=0.0):
    robot = qingzhui()
    terrain = as_terrain(heightmap)
    support = support_field(terrain, robot.foot_radius + BlcParameters().support_margin,
                            BlcParameters().support_drop)
    return canonical_stance(robot.nominal_footholds, robot.box_half_sizes, x, y, yaw, terrain, support,
                            robot.foot_radius, TOL), robot, support


def test_level_ground_gives_the_nominal_stance():
    stance, robot, support = _stance(_map(), 0.3, 0.2, 0.4)
    c, s = math.cos(0.4), math.sin(0.4)
    nominal = np.array([0.3, 0.2]) + robot.nominal_footholds[:, :2] @ np.array([[c, s], [-s, c]])
    assert stance.fixed.all() and not stance.moved.any()
    np.testing.assert_allclose(stance.feet[:, :2], nominal, atol=1e-12)
    np.testing.assert_allclose(stance.feet[:, 2], robot.foot_radius)


def test_a_foot_on_an_edge_moves_to_clear_ground_and_one_too_far_stays_free():
    robot = qingzhui()
    # The front foot (leg 0, 0.75 m ahead of the CoM) on the step's edge at x = 0.5.
    stance, _, support = _stance(_map(step_x=0.5), 0.5 - robot.nominal_footholds[0, 0])
    assert stance.moved[0] and stance.fixed[0] and not stance.moved[1:].any()
    foot = stance.feet[0]
    # To the centre of the nearest clear cell: off the edge, sideways by at most half a cell.
    assert abs(foot[0] - 0.5) > 0.05 and abs(foot[1]) <= RES / 2 + 1e-9
    assert support.margin(foot[0], foot[1]) >= TOL - 1e-9
    assert foot[2] == pytest.approx((0.1 if foot[0] > 0.5 else 0.0) + robot.foot_radius)
    # In the middle of a 0.6 m wide ramp steeper than the friction cone (no support there)
    # the nearest clear ground is farther than the box allows: the foot stays free, on its
    # nominal foothold.
    stance, _, _ = _stance(_map(ramp=(0.2, 0.8)), 0.5 - robot.nominal_footholds[0, 0])
    assert not stance.fixed[0] and not stance.moved[0] and stance.fixed[1:].all()
    assert stance.feet[0, 0] == pytest.approx(0.5) and stance.feet[0, 2] == pytest.approx(0.45 + robot.foot_radius)


def test_a_mission_ends_in_the_canonical_stance_the_map_assumes():
    """A 1 m mission whose target puts the front foot on a step's edge: with terminal_stance
    "canonical" it plans and every foot ends within the tolerance of the canonical stance (the
    front foot moved off the edge); the capability map's canonical feet at that pose are the
    BLC's; and "free" is the default and bounds nothing."""
    heightmap = _map(step_x=0.5)
    robot = qingzhui()
    target_x = 0.5 - robot.nominal_footholds[0, 0]
    params = BlcParameters(max_iterations=60, time_limit=60.0, terminal_stance="canonical")
    terrain = as_terrain(heightmap)
    start, rpy, feet = standing_start(robot, terrain, target_x - 1.0, 0.0, 0.0)
    task = BlcTask(target=(target_x, 0.0, 0.0), start_position=tuple(start), start_rpy=tuple(rpy), start_feet=feet,
                   duration=3.6)
    solution = solve_blc(task, robot, heightmap, params)
    assert solution.success, solution.reason
    end_feet = np.array([solution.foot_positions[leg].value(solution.duration).ravel() for leg in range(6)])
    stance, _, _ = _stance(heightmap, target_x)
    assert stance.moved[0] and stance.fixed.all()
    assert np.abs(end_feet[:, :2] - stance.feet[:, :2]).max() <= TOL + 1e-6

    # The map's canonical feet at the base pose of that target (the CoM target less com_B).
    com_B = np.asarray(robot.com_B)
    feet_W = P.canonical_feet_W(heightmap, target_x - com_B[0], -com_B[1], 0.0, get_topology("nominal"),
                                DEFAULT_PARAMS.foot_radius)
    np.testing.assert_allclose(feet_W[:, :2], stance.feet[:, :2], atol=1e-9)

    # "free": no terminal bounds, as every BLC before issue 54.
    schedule = make_gait("tripod", 6, 3.6, stand_duration=0.2)
    f = BlcFormulation(robot, terrain, BlcParameters(), schedule, start_position=start, start_rpy=rpy,
                       start_feet=feet, target=(target_x, 0.0, 0.0))
    assert f.terminal is None
    last = np.concatenate([idx[-1] for idx in f.variables.footholds])
    assert np.isinf(f.lower[last]).all() and np.isinf(f.upper[last]).all()


def test_bad_stance_settings_name_the_field():
    with pytest.raises(QzError, match="blc.terminal_stance"):
        BlcParameters(terminal_stance="tidy")
    with pytest.raises(QzError, match="blc.terminal_foothold_tolerance"):
        BlcParameters(terminal_foothold_tolerance=0.0)
    with pytest.raises(QzError, match="capability_mdp.stance"):
        from qz_drake.planning.capability_mdp import CapabilityMdpConfig

        CapabilityMdpConfig(stance="tidy").check()
    with pytest.raises(QzError, match="trials.blc_terminal_stance"):
        from qz_drake.capability.trials import TrialConfig

        TrialConfig(blc_terminal_stance="tidy")


def test_a_mission_down_a_flight_refused_in_the_canonical_stance_plans_on_the_free_rung():
    """Down a flight (0.36 m in four steps, as the tuning world stairs-hard-1000's): from the
    canonical stance 0.9 m along, a 1 m mission that must end in the canonical stance is not
    planned in 12 iterations, and the ladder's "free" rung (the end stance left to the BLC)
    plans it."""
    from qz_drake.config import MissionTiming
    from qz_drake.scene import standing_state
    from qz_drake.systems.blc_plan import blc_mission_planner, expected_end
    from qz_drake.systems.mission_sequencer import measured_start

    n = 120
    origin = (-2.0, -3.0)
    xs = origin[0] + RES * np.arange(n)
    row = np.select([xs < 1.025, xs < 1.075, xs < 1.425, xs < 1.475], [0.36, 0.27, 0.18, 0.09], 0.0)
    heightmap = HeightMap(np.tile(row, (n, 1)), RES, origin)
    planner = blc_mission_planner(heightmap, DEFAULT_PARAMS, MissionTiming(),
                                  BlcParameters(max_iterations=12, time_limit=60.0, terminal_stance="canonical"))
    start = measured_start(standing_state(heightmap, get_topology("nominal"), xy=(-0.1, 0.0), yaw=0.0), 0.0,
                           DEFAULT_PARAMS)
    lead_in, reason = planner(start, (0.9, 0.0, 0.0), "nominal", 0.0)
    assert lead_in is not None, reason
    start = expected_end(lead_in)
    plan, reason = planner(start, (1.9, 0.0, 0.0), "nominal", start.time)
    assert plan is None and "BLC:" in reason
    plan, reason = planner(start, (1.9, 0.0, 0.0), "nominal", start.time, rung="free")
    assert plan is not None, reason
    assert planner.last_solution.params.terminal_stance == "free"


def test_the_capability_map_asks_about_the_canonical_stance_where_told():
    """sample_map_inputs with stance "canonical": every cell's and heading's feet are the
    canonical stance's (in the heading frame), and differ from the nominal inputs exactly where
    the rule moved a foot (here: feet on the step's edge)."""
    from qz_drake.capability.model_base import sample_map_inputs

    heightmap = _map(step_x=0.5)
    nominal = sample_map_inputs(heightmap, ["nominal"], anchor=(0.0, 0.0)).feet["nominal"]
    canonical = sample_map_inputs(heightmap, ["nominal"], anchor=(0.0, 0.0), stance="canonical").feet["nominal"]
    xs, ys = P.grid_centres(heightmap, anchor=(0.0, 0.0))
    k, gy, gx = np.meshgrid(np.arange(8), ys, xs, indexing="ij")
    topology = get_topology("nominal")
    yaw = P.heading_yaw(k)
    feet_W = P.canonical_feet_W(heightmap, gx, gy, yaw, topology, DEFAULT_PARAMS.foot_radius)
    ground = P.ground_reference(heightmap, gx, gy)
    np.testing.assert_allclose(canonical, P.feet_in_heading_frame(feet_W, gx, gy, yaw, ground), atol=1e-6)
    moved = np.abs(canonical - nominal).max(axis=-1) > 1e-6
    nominal_W = P.nominal_feet_W(heightmap, gx, gy, yaw, topology, DEFAULT_PARAMS.foot_radius)
    near_edge = np.abs(nominal_W[..., 0] - 0.5) < 0.1
    assert moved.any() and np.array_equal(moved, moved & near_edge)
    with pytest.raises(QzError, match="capability_mdp.stance"):
        from qz_drake.capability.model_base import predict_map

        predict_map(None, heightmap, ["nominal"], stance="tidy")
