"""IK tracking of a body-and-feet plan: references by hand, and a 1 m walk in simulation."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from qz_drake.config import Scenario, TerrainConfig
from qz_drake.robot import kinematics
from qz_drake.robot.topology import get_topology
from qz_drake.simulation import add_tracking_controller
from qz_drake.station import make_station
from qz_drake.systems.ik_tracker import InverseKinematicsTracker, joint_reference, joint_references
from qz_drake.systems.reference_gait import TripodGaitPlan
from qz_drake.state_layout import tilt_deg
from qz_drake.terrain import make_terrain


def _plan(topology="nominal", **kw):
    return TripodGaitPlan(heightmap=make_terrain("flat"), topology=get_topology(topology),
                          start_xy_yaw=(0.0, 0.0, 0.0), goal_xy_yaw=(1.0, 0.0, 0.0),
                          start_time=0.5, duration=4.0, **kw)


def test_plan_alternates_tripods_and_keeps_stance_feet_still():
    plan = _plan()
    assert plan.contact(0.6).tolist() == [False, True, False, True, False, True]  # A swings first
    assert plan.contact(1.0).tolist() == [True, False, True, False, True, False]
    # A stance foot does not move; a swinging one rises above the ground.
    np.testing.assert_allclose(plan.foot_positions(1.0)[0], plan.foot_positions(1.2)[0])
    assert plan.foot_positions(0.7)[0, 2] > 0.03 + 0.05
    # Three stance feet carry the weight.
    assert plan.foot_forces(1.0)[:, 2].sum() == pytest.approx(plan.params.total_mass * 9.81)
    np.testing.assert_allclose(plan.base_position(plan.end_time)[:2], [1.0, 0.0], atol=1e-9)


def test_joint_reference_reproduces_the_planned_feet():
    plan = _plan("front_bend")
    for t in (0.5, 0.7, 1.9, 3.3):
        q, ok = joint_reference(plan, t, plan.topology, roll_compensation=False)
        assert ok.all()
        # Forward kinematics of the references put the feet where the plan says, relative to
        # the planned body (flat, level body: a translation).
        p_B = kinematics.all_foot_positions(q)
        np.testing.assert_allclose(p_B + plan.base_position(t), plan.foot_positions(t), atol=1e-9)
        # Rolling compensation moves only stance feet that have been down a while, by at most
        # the foot radius times the shank's turn (well under 2 cm here), along the ground.
        q_c, _ = joint_reference(plan, t, plan.topology)
        shift = kinematics.all_foot_positions(q_c) - p_B
        assert np.all(np.abs(shift) < 0.02) and np.all(np.abs(shift[:, 2]) < 1e-9)
        assert np.all(shift[~plan.contact(t)] == 0.0)
    mid_stance = 1.9  # group A in stance since 1.3 s
    shift = kinematics.all_foot_positions(joint_reference(plan, mid_stance, plan.topology)[0]) - \
        kinematics.all_foot_positions(joint_reference(plan, mid_stance, plan.topology, roll_compensation=False)[0])
    assert np.linalg.norm(shift[0]) > 1e-3


def test_a_plans_references_solved_at_once_are_those_solved_one_by_one():
    """The tracker solves a plan's references together when it arrives (joint_references): the
    same numbers as joint_reference time by time, the rolling compensation included, before the
    plan, along it and past its end."""
    for topology, start, goal in (("front_bend", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
                                  ("split_up", (0.3, -0.2, 0.7), (1.2, 0.5, 1.2)),
                                  ("nominal", (0.3, -0.2, -2.1), (1.2, 0.5, -1.6))):
        plan = TripodGaitPlan(heightmap=make_terrain("flat"), topology=get_topology(topology), start_xy_yaw=start,
                              goal_xy_yaw=goal, start_time=0.5, duration=4.0)
        times = np.concatenate([[0.2, 0.5], np.arange(0.5, 4.6, 0.005) + 0.005, [5.0]])
        q, ok = joint_references(plan, times, plan.topology)
        assert q.shape == (len(times), 18) and ok.shape == (len(times), 6)
        for k, t in enumerate(times):
            q_one, ok_one = joint_reference(plan, t, plan.topology)
            np.testing.assert_array_equal(q[k], q_one, err_msg=f"{topology} at t = {t}")
            np.testing.assert_array_equal(ok[k], ok_one)
    np.testing.assert_array_equal(joint_references(plan, times[:7], plan.topology, roll_compensation=False)[0],
                                  [joint_reference(plan, t, plan.topology, roll_compensation=False)[0] for t in times[:7]])


def test_the_tracker_holds_the_same_references_solved_at_once_or_one_by_one(monkeypatch):
    """Every update reads the reference solved when the plan arrived: the walk is the one of
    solving at each update, to the bit."""
    def walk():
        scenario = Scenario(terrain=TerrainConfig(kind="flat", contact="boxes", region=[-2, 4, -2, 2]))
        builder = DiagramBuilder()
        station, info = make_station(scenario)
        builder.AddSystem(station)
        plan = _plan()
        tracker, _ = add_tracking_controller(builder, station, info, plan, kp=1500.0, kd=30.0)
        log = LogVectorOutput(tracker.GetOutputPort("desired_state"), builder)
        state = LogVectorOutput(station.GetOutputPort("state"), builder)
        simulator = Simulator(builder.Build())
        simulator.AdvanceTo(1.2)
        context = simulator.get_context()
        return tracker, log.FindLog(context).data(), state.FindLog(context).data()

    tracker, *at_once = walk()
    assert tracker._solved is not None and len(tracker._solved[1]) > 800  # the plan solved at once
    from qz_drake.systems import ik_tracker

    monkeypatch.setattr(ik_tracker, "SOLVE_AHEAD", 30)  # a long plan: a window at a time
    tracker, *windows = walk()
    assert 30 <= len(tracker._solved[1]) <= 33
    monkeypatch.setattr(InverseKinematicsTracker, "_solve_plan", lambda self, plan, t: None)
    _, *one_by_one = walk()
    for a, b, c in zip(at_once, windows, one_by_one):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)


def test_walks_one_metre_on_flat_ground():
    scenario = Scenario(terrain=TerrainConfig(kind="flat", contact="boxes", region=[-2, 4, -2, 2]))
    builder = DiagramBuilder()
    station_diagram, info = make_station(scenario)
    station = builder.AddSystem(station_diagram)
    plan = TripodGaitPlan(heightmap=info.heightmap, topology=info.topology, start_xy_yaw=(0, 0, 0),
                          goal_xy_yaw=(1.0, 0, 0), start_time=0.5, duration=4.0)
    add_tracking_controller(builder, station, info, plan, kp=1500.0, kd=30.0)
    log = LogVectorOutput(station.GetOutputPort("state"), builder, 0.01)
    trunk = LogVectorOutput(station.GetOutputPort("trunk_contact"), builder, 0.01)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(plan.end_time + 0.5)
    context = simulator.get_context()
    x = log.FindLog(context).data().T
    times = log.FindLog(context).sample_times()
    planned = np.array([plan.base_position(t) for t in times])
    final_error = np.linalg.norm(x[-1, 4:6] - [1.0, 0.0])
    rms = np.sqrt(np.mean(np.sum((x[:, 4:7] - planned) ** 2, axis=1)))
    assert final_error < 0.15
    # The bound; without the rolling compensation the body drifted 7 cm ahead (RMS 4.7 cm).
    assert rms < 0.05
    assert final_error < 0.05
    assert max(tilt_deg(s) for s in x) < 5.0
    assert not trunk.FindLog(context).data().any()


def test_rotation_vectors_match_scipy():
    from scipy.spatial.transform import Rotation

    from qz_drake.systems.ik_tracker import _rotation_vectors

    vectors = np.random.default_rng(3).normal(size=(10, 3)) * 0.7
    np.testing.assert_allclose(_rotation_vectors(Rotation.from_rotvec(vectors).as_matrix()), vectors, atol=1e-9)
    np.testing.assert_allclose(_rotation_vectors(np.eye(3)), np.zeros(3))


@pytest.mark.parametrize("terrain", ["rough", "stairs"])
def test_a_tripod_plan_read_at_many_times_at_once_is_read_time_by_time(terrain):
    """The tracker reads a tripod plan's feet and body at all of a mission's times at once (the
    ground under a swing queried once a swing): the same numbers as one time at a time, to the
    bit, before the plan, on the phase boundaries, along it and past its end."""
    plan = TripodGaitPlan(heightmap=make_terrain(terrain), topology=get_topology("front_bend"),
                          start_xy_yaw=(0.2, -0.1, 0.3), goal_xy_yaw=(1.1, 0.3, 0.6), start_time=0.5, duration=4.0)
    boundaries = [land for holds in plan._holds for land, _ in holds]
    times = np.concatenate([[0.0, 0.5], np.arange(0.5, plan.end_time + 0.5, 0.005), boundaries,
                            np.asarray(boundaries) - plan.phase_duration])
    np.testing.assert_array_equal(plan.foot_positions_many(times), [plan.foot_positions(t) for t in times])
    np.testing.assert_array_equal(plan.base_positions_many(times), [plan.base_position(t) for t in times])
    assert plan.foot_positions_many([]).shape == (0, 6, 3) and plan.base_positions_many([]).shape == (0, 3)
    q, _ = joint_references(plan, times[:50], plan.topology)
    np.testing.assert_array_equal(q, [joint_reference(plan, t, plan.topology)[0] for t in times[:50]])
