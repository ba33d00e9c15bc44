"""The BLC ladder on a mission a walk met (issue 52): a step down a 0.18 m platform edge of the
Fig. 9 world stairs-hard-12, from the start the BLC's own plan of the metre before ended in
(benchmarks/blc_refusals.py, the sweep down that edge, 0.6 m before it)."""

import numpy as np

from qz_drake.config import MissionTiming
from qz_drake.experiments.worlds import make_task
from qz_drake.robot.params import DEFAULT_PARAMS
from qz_drake.systems.blc_plan import blc_mission_planner
from qz_drake.systems.mission_sequencer import MissionStart
from qz_drake.trajopt.parameters import BlcParameters

# The front foot already on the lower step, the others on the platform. [m, rad]
START = MissionStart(
    time=0.0, xy_yaw=(1.9512774800722492, 0.025000000000000248, 0.0), base_z=0.8693958575969579,
    roll_pitch=(5.0552324654080386e-15, 0.05988138748490352),
    feet_W=np.array([[2.694464209485666, 0.024999999999998183, 0.21],
                     [2.2671494305178816, -0.5413409300047294, 0.39],
                     [1.5318597511587446, -0.5291277740575786, 0.38999999999999996],
                     [1.1655471334247356, 0.025000000000002867, 0.39],
                     [1.5318597511587606, 0.5791277740576007, 0.38999999999999996],
                     [2.2671494305178905, 0.5913409300047309, 0.38999999999999996]]))
TARGET = (2.95, 0.025, 0.0)


def test_a_step_down_the_first_solve_refuses_plans_one_tripod_cycle_longer_and_holds_the_dense_check():
    world = make_task("stairs", "hard", 12).heightmap
    # The Fig. 9 experiment's BLC: 30 Ipopt iterations a solve.
    planner = blc_mission_planner(world, DEFAULT_PARAMS, MissionTiming(),
                                  BlcParameters(max_iterations=30, time_limit=30.0))
    plan, reason = planner(START, TARGET, "nominal", 0.0)
    assert plan is None and "Max iteration exceeded" in reason
    plan, reason = planner(START, TARGET, "nominal", 0.0, rung="cycles+1")
    assert plan is not None, reason
    solution = plan.solution
    assert solution.success and solution.dense.passed
    assert solution.duration == 4.0 + 2 * MissionTiming().phase_duration
    np.testing.assert_allclose(plan.base_position(plan.end_time)[:2], TARGET[:2], atol=0.01)
    # The front feet went down both steps to the ground (sphere centres 0.03 m up), the rear
    # ones are still on the platform (0.39 m).
    np.testing.assert_allclose(plan.foot_positions(plan.end_time)[:, 2], [0.03, 0.03, 0.39, 0.39, 0.39, 0.03],
                               atol=0.005)


def test_a_mission_refused_for_where_it_ends_plans_ending_a_little_nearer():
    # Up the Fig. 9 world stairs-hard-3 from standing 1.4 m before the first riser: a 1 m move
    # ending 0.40 m before it is refused (and one cycle longer, and in two halves); ending
    # 0.1 m nearer plans.
    from qz_drake.robot.topology import get_topology
    from qz_drake.scene import standing_state
    from qz_drake.systems.mission_sequencer import measured_start

    world = make_task("stairs", "hard", 3).heightmap
    riser, y = -1.05, 0.125
    start = measured_start(standing_state(world, get_topology("nominal"), xy=(riser - 1.4, y)), 0.0, DEFAULT_PARAMS)
    planner = blc_mission_planner(world, DEFAULT_PARAMS, MissionTiming(),
                                  BlcParameters(max_iterations=30, time_limit=30.0))
    target = (riser - 0.4, y, 0.0)
    plan, reason = planner(start, target, "nominal", 0.0)
    assert plan is None, "the first solve planned: the case no longer shows the rung"
    plan, reason = planner(start, target, "nominal", 0.0, rung="short")
    assert plan is not None and plan.solution.success and plan.solution.dense.passed, reason
    np.testing.assert_allclose(plan.base_position(plan.end_time)[:2], (riser - 0.5, y), atol=0.01)
