"""A mission starts where the robot stands (issue 37's gap between trials and walks): a foot
that starts outside its kinematic box keeps the room it stands in until its second stance,
so that such a start can be planned, and the plan holds the box from then on."""

import numpy as np
import pytest

from qz_drake.terrain.heightmap import HeightMap
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc, standing_start

BLOCK = 0.15  # [m] under MF's start foot: 5 cm above the top of its 0.1 m box along z


@pytest.fixture(scope="module")
def block_start():
    """Flat ground with a 0.3 m square block under MF's nominal foothold; the body stands as on
    flat ground, MF on the block."""
    robot = qingzhui("nominal")
    res = 0.02
    xs = np.arange(-1.5, 3.0 + 1e-9, res)
    ys = np.arange(-1.5, 1.5 + 1e-9, res)
    X, Y = np.meshgrid(xs, ys)
    mf = robot.nominal_footholds[0]
    heights = np.where((np.abs(X - mf[0]) < 0.15) & (np.abs(Y - mf[1]) < 0.15), BLOCK, 0.0)
    world = HeightMap(heights=heights, resolution=res, origin=(xs[0], ys[0]))
    start, rpy, feet = standing_start(robot, None)
    feet[0, 2] += BLOCK
    task = BlcTask(target=(1.0, 0.0, 0.0), duration=3.2, start_position=tuple(start),
                   start_rpy=tuple(rpy), start_feet=feet)
    return robot, world, task


def test_a_foot_that_starts_above_its_box_is_planned_from_where_it_stands(block_start):
    robot, world, task = block_start
    solution = solve_blc(task, robot, world, BlcParameters(max_iterations=60, time_limit=60.0))
    assert solution.success, solution.reason
    # MF steps off the block and stands inside its box from its second stance on.
    mf = solution.foot_positions[0]
    assert mf.value(solution.duration).ravel()[2] == pytest.approx(robot.foot_radius, abs=0.01)
    assert solution.dense.max_box_excess <= BlcParameters().dense_box_tolerance


def test_without_the_start_room_the_same_start_cannot_be_planned(block_start):
    robot, world, task = block_start
    solution = solve_blc(task, robot, world, BlcParameters(max_iterations=30, time_limit=60.0,
                                                           relax_start_boxes=False))
    assert not solution.success
    assert "kinematics (t = 0.00 s)" in solution.reason


def test_the_box_bounds_widen_only_the_axis_a_start_foot_exceeds_and_only_until_its_second_stance(
        block_start):
    from qz_drake.trajopt.formulation import START_BOX_ALLOWANCE, BlcFormulation, first_step_end
    from qz_drake.trajopt.gait import make_gait
    from qz_drake.trajopt.terrain import as_terrain

    robot, world, task = block_start
    params = BlcParameters()
    schedule = make_gait("tripod", robot.num_legs, task.duration, stand_duration=params.stand_duration)
    f = BlcFormulation(robot, as_terrain(world), params, schedule, start_position=np.array(task.start_position),
                       start_rpy=np.array(task.start_rpy), start_feet=task.start_feet,
                       target=task.target)
    times = np.linspace(0.0, task.duration, 81)
    lower, upper = f.box_bounds(times)
    box = robot.box_half_sizes
    q0 = f.start_box_offsets()
    assert q0[0, 2] == pytest.approx(box[0, 2] + 0.05, abs=1e-6)
    early = times <= first_step_end(schedule, 0) + 1e-9
    np.testing.assert_allclose(upper[early, 0, 2], q0[0, 2] + START_BOX_ALLOWANCE)
    np.testing.assert_allclose(upper[~early, 0, 2], box[0, 2])
    # Every other bound is the box.
    mask = np.zeros(upper.shape, dtype=bool)
    mask[early, 0, 2] = True
    np.testing.assert_allclose(upper[~mask], np.broadcast_to(box, upper.shape)[~mask])
    np.testing.assert_allclose(lower, -np.broadcast_to(box, lower.shape))
    # A start inside every box changes nothing.
    flat = BlcFormulation(robot, as_terrain(None), params, schedule, start_position=np.array(task.start_position),
                          start_rpy=np.array(task.start_rpy), start_feet=standing_start(robot, None)[2],
                          target=task.target)
    lower, upper = flat.box_bounds(times)
    np.testing.assert_allclose(upper, np.broadcast_to(box, upper.shape))
