"""A task of a schedule met before reuses that schedule's parts (issue 11: the program of a
task of the same size is not built from scratch each mission): the variables, samples and
Jacobian patterns are shared, while everything that belongs to the task (terrain, support,
start, target) is its own, and a solve gives the same plan, bit for bit, as from scratch."""

import numpy as np
import pytest

from qz_drake.trajopt import formulation as fm
from qz_drake.trajopt import terrain as tt
from qz_drake.trajopt.formulation import BlcFormulation
from qz_drake.trajopt.gait import make_gait
from qz_drake.trajopt.initial_guess import straight_line_guess
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import hyq
from qz_drake.trajopt.solver import BlcTask, solve_blc, standing_start
from qz_drake.trajopt.verdict import dense_check

PARAMS = BlcParameters(time_limit=60.0)


def _formulation(terrain, target=(1.0, 0.0, 0.0)):
    robot = hyq()
    schedule = make_gait("trot", robot.num_legs, 2.4, stand_duration=PARAMS.stand_duration)
    start, rpy, feet = standing_start(robot, terrain)
    return BlcFormulation(robot, terrain, PARAMS, schedule, start_position=start, start_rpy=rpy,
                          start_feet=feet, target=target)


def _jacobians(f, x):
    return {c.name: c.jacobian(x, f.variables.num_vars).toarray() for c in f.nonlinear}


def test_a_second_task_of_the_schedule_shares_its_structure_but_not_its_terrain():
    fm.clear_schedule_parts()
    flat = _formulation(tt.flat())
    stairs_terrain = tt.stairs(start_x=1.0, run=0.4, rises=(0.2, 0.2))
    stairs = _formulation(stairs_terrain, target=(1.2, 0.1, 0.2))
    assert stairs.variables is flat.variables
    shared = {c.name: c for c in flat.nonlinear}
    # Flat ground needs no support rows; the stairs do, with their own support field.
    assert "support" not in shared
    [support] = [c for c in stairs.nonlinear if c.name == "support"]
    assert support.field is stairs.support
    for c in stairs.nonlinear:
        if c.name in shared:
            assert c.rows is shared[c.name].rows  # the pattern is shared ...
        if hasattr(c, "terrain"):
            assert c.terrain is stairs_terrain  # ... the terrain is the task's own
    assert flat.nonlinear[0].binding_structure is stairs.nonlinear[0].binding_structure
    # The same program as one built from scratch: bounds, values and Jacobians at a point
    # where the feet are on the stairs.
    x = straight_line_guess(stairs)
    fm.clear_schedule_parts()
    fresh = _formulation(stairs_terrain, target=(1.2, 0.1, 0.2))
    assert fresh.variables is not stairs.variables
    np.testing.assert_array_equal(fresh.lower, stairs.lower)
    np.testing.assert_array_equal(fresh.upper, stairs.upper)
    assert [c.name for c in fresh.nonlinear] == [c.name for c in stairs.nonlinear]
    for a, b in zip(fresh.nonlinear, stairs.nonlinear):
        np.testing.assert_array_equal(a.evaluate(x), b.evaluate(x))
    expected, got = _jacobians(fresh, x), _jacobians(stairs, x)
    for name in expected:
        np.testing.assert_array_equal(expected[name], got[name])
    # The terrain really enters: the stairs' terrain rows differ from the flat task's.
    [a] = [c for c in stairs.nonlinear if c.name == "terrain/swing"]
    [b] = [c for c in flat.nonlinear if c.name == "terrain/swing"]
    assert np.abs(a.evaluate(x) - b.evaluate(x)).max() > 0.1
    # The dense verdict too, whose structures are cached with the schedule.
    assert dense_check(stairs, x).failures == dense_check(fresh, x).failures
    assert dense_check(stairs, x).min_swing_clearance == dense_check(fresh, x).min_swing_clearance
    # A plan of flat ground walks through the stairs: only the stairs' own check sees it.
    x_flat = straight_line_guess(flat)
    assert dense_check(flat, x_flat).min_swing_clearance > -1e-9
    assert dense_check(stairs, x_flat).min_swing_clearance < -0.1


def test_a_solve_with_the_cached_parts_is_the_solve_from_scratch():
    task = BlcTask(target=(1.0, 0.0, 0.0), duration=2.4)
    terrain = tt.stairs(start_x=1.0, run=0.4, rises=(0.2, 0.2))
    fm.clear_schedule_parts()
    scratch = solve_blc(task, hyq(), terrain, PARAMS)
    # A flat task of the same schedule first, then the stairs from the cache.
    solve_blc(task, hyq(), None, PARAMS)
    cached = solve_blc(task, hyq(), terrain, PARAMS)
    assert scratch.success and cached.success
    np.testing.assert_array_equal(cached.x, scratch.x)
    assert cached.iterations == scratch.iterations


def test_the_cache_keeps_a_bounded_number_of_schedules():
    fm.clear_schedule_parts()
    robot = hyq()
    for k in range(fm.SCHEDULE_PARTS_CACHE_SIZE + 3):
        schedule = make_gait("trot", robot.num_legs, 1.0 + 0.1 * k)
        fm.schedule_parts(robot, PARAMS, schedule, {})
    assert len(fm._schedule_parts) == fm.SCHEDULE_PARTS_CACHE_SIZE
    # Other parameters are another entry, not the cached parts of the defaults.
    schedule = make_gait("trot", robot.num_legs, 1.0 + 0.1 * (fm.SCHEDULE_PARTS_CACHE_SIZE + 2))
    same = fm.schedule_parts(robot, PARAMS, schedule, {})
    assert fm.schedule_parts(robot, BlcParameters(time_limit=60.0), schedule, {}) is same
    assert fm.schedule_parts(robot, BlcParameters(kinematics_dt=0.02), schedule, {}) is not same


def test_a_constraint_takes_only_data_it_has():
    f = _formulation(tt.flat())
    [c] = [c for c in f.nonlinear if c.name == "terrain/swing"]
    with pytest.raises(AttributeError, match="no data 'field'"):
        c.on(field=None)
    assert c.on(terrain=c.terrain) is c
