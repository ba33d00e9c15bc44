"""Gaits, robot presets and warm starts of the BLC."""

import numpy as np
import pytest

from qz_drake.trajopt import terrain as tt
from qz_drake.trajopt.gait import make_gait
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import hyq, make_robot, qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc

# The tests check plans, not speed: a loaded machine must not turn a solve into a time-limit
# failure.
PARAMS = BlcParameters(time_limit=60.0)


@pytest.mark.parametrize("gait", ["tripod", "tetrapod", "wave"])
def test_every_foot_swings_and_groups_follow_the_gait(gait):
    schedule = make_gait(gait, 6, 3.0)
    t = np.linspace(0.0, 3.0, 601)
    contact = schedule.in_contact(t)
    assert contact[0].all() and contact[-1].all()  # standing at both ends
    assert all((~contact[:, leg]).any() for leg in range(6))
    swinging = (~contact).sum(axis=1)
    assert swinging.max() == {"tripod": 3, "tetrapod": 2, "wave": 1}[gait]
    if gait == "tripod":  # group A = MF, RB, LB swing together, then group B
        assert not np.any(contact[:, [0, 2, 4]].any(axis=1) & ~contact[:, [0, 2, 4]].all(axis=1))


def test_scalar_contact_queries_agree_with_the_vectorised_ones():
    # Trackers ask contact_at and stance_intervals at every update; they must give what
    # in_contact does, at the phase boundaries themselves too (stance on [touchdown, liftoff)).
    schedule = make_gait("tripod", 6, 3.0)
    bounds = np.concatenate([schedule.phase_boundaries(leg) for leg in range(6)])
    t = np.concatenate([np.linspace(-0.5, 3.5, 801), bounds, np.nextafter(bounds, -np.inf)])
    expected = schedule.in_contact(t)
    assert np.array_equal(np.array([schedule.contact_at(ti) for ti in t]), expected)
    assert not expected.all() and expected.any()
    for leg in range(6):
        b = schedule.phase_boundaries(leg)
        assert schedule.stance_intervals(leg) == [(b[i], b[i + 1]) for i in range(0, len(b) - 1, 2)]
        assert all(type(x) is float for pair in schedule.swing_intervals(leg) for x in pair)


# The wave gait (one foot at a time, 0.2 s swings) no longer converges within the limit since
# forces are held in their cone along every polynomial and Eq. 2 is sampled every 0.05 s
# (issue 11; BENCHMARKS.md, blc).
@pytest.mark.parametrize("gait", ["tetrapod"])
def test_hexapod_gaits_solve_on_flat_ground(gait):
    solution = solve_blc(BlcTask(target=(0.6, 0.0, 0.0), duration=3.0, gait=gait), params=PARAMS)
    assert solution.success, solution.reason


def test_hyq_trot_solves_towr_flat_task_and_stairs():
    # TOWR's block (0.5 m) no longer passes: its plans dipped 3-4 cm into the block's edge
    # between clearance samples and broke Eq. 2 between dynamics samples; held densely, it
    # does not converge within the limit (BENCHMARKS.md, blc).
    robot = hyq()
    assert robot.mass == pytest.approx(83.0) and robot.num_legs == 4
    flat = solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=2.0), robot, params=PARAMS)
    assert flat.success, flat.reason
    stairs = solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=2.4), robot,
                       tt.stairs(start_x=1.0, run=0.4, rises=(0.2, 0.2)), PARAMS)
    assert stairs.success, stairs.reason
    feet = stairs.sample(100.0)["foot_pos"][-1]
    # The front feet end on the stairs (the first step is 0.2 m high from x = 1.0).
    assert np.sum(feet[:, 0] > 1.0) >= 2 and np.all(feet[feet[:, 0] > 1.0, 2] > 0.19)


def test_all_topologies_solve_a_short_walk():
    for topology in ("nominal", "hind_bend", "front_bend", "hind_1_bend", "front_1_bend", "split_up"):
        solution = solve_blc(BlcTask(target=(0.5, 0.0, 0.0), duration=2.0, topology=topology),
                             params=PARAMS)
        assert solution.success, (topology, solution.reason)


def test_the_quadruped_preset_solves_a_short_walk_sampled_on_towr_grid():
    """Paper 003's 2.9 kg quadruped: with Eq. 2's angular half every 0.05 s Ipopt does not
    converge (its inertia is 300x Qingzhui's smaller); on TOWR's 0.1 s grid it does, but the
    plan breaks the angular half between samples, which the dense verdict reports."""
    quad = make_robot("quadruped")
    params = BlcParameters(time_limit=60.0, dynamics_dt=0.1)
    solution = solve_blc(BlcTask(target=(0.2, 0.0, 0.0), duration=2.0), quad, params=params)
    assert solution.max_violation < 1e-3
    assert not solution.success and "angular single-rigid-body residual" in solution.reason


def test_warm_start_from_a_previous_solution():
    task = BlcTask(target=(1.0, 0.0, 0.0), duration=2.0)
    cold = solve_blc(task, params=PARAMS)
    warm = solve_blc(task, params=PARAMS, initial_guess=cold)
    # Iterations are not asserted: from an exact solution Ipopt's interior point first moves
    # off the active bounds (measured: 12 iterations against 5 from the straight line).
    assert warm.success, warm.reason
    # A feasibility problem has many solutions: the warm solve may end at another one.
    np.testing.assert_allclose(warm.body_position.value(2.0).ravel()[:2], [1.0, 0.0], atol=1e-6)
    # A nearby task from the same guess (a replan after the target moved).
    moved = solve_blc(BlcTask(target=(1.1, 0.05, 0.0), duration=2.0), params=PARAMS,
                      initial_guess=cold)
    assert moved.success, moved.reason
    # The next mission, from where this one ends, guessed from this one shifted by its duration.
    end = cold.duration
    feet = np.array([pp.value(end).ravel() for pp in cold.foot_positions])
    nxt = BlcTask(target=(2.0, 0.0, 0.0), duration=2.0,
                  start_position=tuple(cold.body_position.value(end).ravel()),
                  start_rpy=tuple(cold.body_rpy.value(end).ravel()), start_feet=feet)
    shifted = solve_blc(nxt, params=PARAMS, initial_guess=cold, time_shift=end)
    assert shifted.success, shifted.reason
    # A guess of the wrong size is an error naming it.
    with pytest.raises(Exception, match="initial_guess"):
        solve_blc(task, initial_guess=np.zeros(3))
    assert qingzhui().num_legs == 6
