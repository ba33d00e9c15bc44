"""TrajectoryOptimizationBLC: solves per mission from the measured state, keeps failures as
results, and closes the loop with the IK tracker and joint PD on the simulated robot."""

import math

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource

from qz_drake.config import Scenario, TerrainConfig
from qz_drake.errors import QzError
from qz_drake.robot.topology import get_topology
from qz_drake.simulation import add_tracking_controller
from qz_drake.station import make_station, standing_state
from qz_drake.config import MissionTiming
from qz_drake.systems.blc import TrajectoryOptimizationBLC
from qz_drake.systems.blc_plan import ChainedPlan, parse_ladder
from qz_drake.state_layout import tilt_deg
from qz_drake.terrain import make_terrain
from qz_drake.trajopt.parameters import BlcParameters

# Missions into a 1 m wall, which no solve can plan: the solves stop after six Ipopt iterations
# instead of at the 5 s time limit (15 s of make test); the first 0.3 m mission takes four.
WALL_BLC = BlcParameters(max_iterations=6)


def _fixed(system, heightmap, state, target, topology="nominal"):
    context = system.CreateDefaultContext()
    system.GetInputPort("state").FixValue(context, state)
    system.GetInputPort("target").FixValue(context, np.asarray(target, dtype=float))
    system.GetInputPort("topology").FixValue(context, AbstractValue.Make(topology))
    system.GetInputPort("heightmap").FixValue(context, AbstractValue.Make(heightmap))
    return context


def test_solves_at_start_and_again_only_when_the_mission_changes():
    heightmap = make_terrain("flat")
    state = standing_state(heightmap, get_topology("nominal"), xy=(0.2, -0.1), yaw=0.3)
    blc = TrajectoryOptimizationBLC(timing=MissionTiming(speed=0.3))
    context = _fixed(blc, heightmap, state, (1.0, 0.2, 0.3))
    simulator = Simulator(blc, context)
    simulator.Initialize()
    assert len(blc.log.solves) == 1 and not blc.log.failures
    plan = blc.GetOutputPort("plan").Eval(context)
    solution = blc.GetOutputPort("solution").Eval(context)
    assert solution.success and plan.solution is solution
    # From the measured base pose to the target.
    np.testing.assert_allclose(plan.base_position(0.0)[:2], [0.2, -0.1], atol=1e-6)
    np.testing.assert_allclose(plan.base_position(plan.end_time)[:2], [1.0, 0.2], atol=1e-3)
    assert plan.base_rpy(plan.end_time)[2] == pytest.approx(0.3, abs=1e-6)
    assert blc.GetOutputPort("contact_schedule").Eval(context) is solution.contact_schedule
    assert blc.GetOutputPort("desired_contact").Eval(context).tolist() == [1.0] * 6
    # Same mission: no new solve. A new target after the plan ended: a new solve from the
    # measured state, starting at the current time.
    simulator.AdvanceTo(plan.end_time + 0.1)
    assert len(blc.log.solves) == 1
    blc.GetInputPort("target").FixValue(context, np.array([0.2, 0.6, 0.3]))
    simulator.AdvanceTo(plan.end_time + 0.2)
    assert len(blc.log.solves) == 2
    second = blc.GetOutputPort("plan").Eval(context)
    assert plan.end_time + 0.1 <= second.start_time <= plan.end_time + 0.2
    np.testing.assert_allclose(second.base_position(second.end_time)[:2], [0.2, 0.6], atol=1e-3)


def test_a_failed_solve_is_logged_and_the_previous_plan_kept():
    heightmap = make_terrain("step", height=1.0, start_x=1.5)  # a 1 m wall
    state = standing_state(heightmap, get_topology("nominal"))
    blc = TrajectoryOptimizationBLC(blc_params=WALL_BLC)
    context = _fixed(blc, heightmap, state, (0.3, 0.0, 0.0))
    simulator = Simulator(blc, context)
    simulator.Initialize()
    first = blc.GetOutputPort("plan").Eval(context)
    assert first is not None
    blc.GetInputPort("target").FixValue(context, np.array([2.0, 0.0, 0.0]))
    simulator.AdvanceTo(0.1)
    assert len(blc.log.failures) == 1 and blc.log.failures[0].reason
    assert blc.GetOutputPort("plan").Eval(context) is first
    assert not blc.GetOutputPort("solution").Eval(context).success


def test_bad_mission_inputs_name_the_field():
    heightmap = make_terrain("flat")
    state = standing_state(heightmap, get_topology("nominal"))
    blc = TrajectoryOptimizationBLC()
    with pytest.raises(QzError, match="topology"):
        Simulator(blc, _fixed(blc, heightmap, state, (1.0, 0.0, 0.0), "crab")).Initialize()
    with pytest.raises(QzError, match="target"):
        Simulator(blc, _fixed(blc, heightmap, state, (math.nan, 0.0, 0.0))).Initialize()


def test_closed_loop_walk_with_the_blc_system_reaches_its_target():
    """Station -> BLC (solved at start from the measured state) -> IK tracker -> joint PD."""
    scenario = Scenario(name="blc_loop", terrain=TerrainConfig(kind="flat", params={"size_x": 5.0}))
    builder = DiagramBuilder()
    station_diagram, info = make_station(scenario)
    station = builder.AddSystem(station_diagram)
    blc = builder.AddSystem(TrajectoryOptimizationBLC(params=info.params))
    target = builder.AddSystem(ConstantVectorSource(np.array([0.8, 0.0, 0.0])))
    topology = builder.AddSystem(ConstantValueSource(AbstractValue.Make("nominal")))
    heightmap = builder.AddSystem(ConstantValueSource(AbstractValue.Make(info.heightmap)))
    builder.Connect(station.GetOutputPort("state"), blc.GetInputPort("state"))
    builder.Connect(target.get_output_port(), blc.GetInputPort("target"))
    builder.Connect(topology.get_output_port(), blc.GetInputPort("topology"))
    builder.Connect(heightmap.get_output_port(), blc.GetInputPort("heightmap"))
    add_tracking_controller(builder, station, info, kp=1500.0, kd=30.0,
                            plan_port=blc.GetOutputPort("plan"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.Initialize()
    plan = blc.GetOutputPort("plan").Eval(blc.GetMyContextFromRoot(simulator.get_context()))
    assert plan is not None
    simulator.AdvanceTo(plan.end_time + 0.5)
    x = station.GetOutputPort("state").Eval(station.GetMyContextFromRoot(simulator.get_context()))
    assert len(blc.log.solves) == 1 and not blc.log.failures
    assert np.hypot(x[4] - 0.8, x[5]) < 0.1
    assert tilt_deg(x) < 10.0


def test_a_mission_asked_ahead_starts_where_the_current_plan_ends():
    heightmap = make_terrain("flat")
    state = standing_state(heightmap, get_topology("nominal"))
    blc = TrajectoryOptimizationBLC()
    context = _fixed(blc, heightmap, state, (0.6, 0.0, 0.0))
    simulator = Simulator(blc, context)
    simulator.Initialize()
    first = blc.GetOutputPort("plan").Eval(context)
    simulator.AdvanceTo(0.5)
    blc.GetInputPort("target").FixValue(context, np.array([1.2, 0.0, 0.0]))
    simulator.AdvanceTo(0.6)
    assert len(blc.log.solves) == 2 and not blc.log.failures
    assert blc.log.solves[1].start_time == pytest.approx(first.end_time)
    # The current plan stays on the output until it ends; then the one solved ahead takes over.
    assert blc.GetOutputPort("plan").Eval(context) is first
    simulator.AdvanceTo(first.end_time + 0.01)
    second = blc.GetOutputPort("plan").Eval(context)
    assert second is not first and second.start_time == pytest.approx(first.end_time)
    np.testing.assert_allclose(second.base_position(second.start_time),
                               first.base_position(first.end_time), atol=1e-6)
    np.testing.assert_allclose(second.foot_positions(second.start_time),
                               first.foot_positions(first.end_time), atol=1e-6)


def _failing_first_attempt(blc, fail_when):
    """Wraps the system's BLC planner: attempts for which ``fail_when(target, rung)`` is true
    are solved, then reported failed (as a dense check failing by a hair would be)."""
    make = blc._planner
    durations = []

    def planner_for(heightmap):
        inner = make(heightmap)

        def plan(start, target, topology, start_time, extra_cycles=0, rung=""):
            result, reason = inner(start, target, topology, start_time, extra_cycles=extra_cycles, rung=rung)
            plan.last_solution = inner.last_solution
            plan.last_iterations = inner.last_iterations
            durations.append(inner.last_solution.duration)
            if fail_when(target, rung):
                return None, "BLC: dense check: (a test's failure)"
            return result, reason

        return plan

    blc._planner = planner_for
    return durations


def _second_mission_failing_first(blc, target_x: float):
    """On flat ground, from the fixed standing state: a 0.3 m first mission plans; then a
    second one to ``target_x`` whose first solve is reported failed. Returns (context, the
    first plan, the solves' durations)."""
    heightmap = make_terrain("flat")
    state = standing_state(heightmap, get_topology("nominal"))
    durations = _failing_first_attempt(blc, lambda target, rung: target[0] > 0.5 and rung == "")
    context = _fixed(blc, heightmap, state, (0.3, 0.0, 0.0))
    simulator = Simulator(blc, context)
    simulator.Initialize()
    first = blc.GetOutputPort("plan").Eval(context)
    simulator.AdvanceTo(first.end_time + 0.05)
    blc.GetInputPort("target").FixValue(context, np.array([target_x, 0.0, 0.0]))
    simulator.AdvanceTo(first.end_time + 0.1)
    return context, first, durations


def test_a_mission_that_failed_to_plan_is_retried_one_tripod_cycle_longer():
    blc = TrajectoryOptimizationBLC(mission_retries=2)
    context, first, durations = _second_mission_failing_first(blc, 1.0)
    # The failed attempt and its retry are both logged; the mission is planned, no failure.
    assert [s.success for s in blc.log.solves] == [True, False, True]
    assert blc.log.retried == [1] and not blc.log.failures
    assert durations[2] == pytest.approx(durations[1] + 2 * MissionTiming().phase_duration)
    second = blc.GetOutputPort("plan").Eval(context)
    assert second is not first
    assert second.end_time - second.start_time == pytest.approx(durations[2])
    np.testing.assert_allclose(second.base_position(second.end_time)[:2], [1.0, 0.0], atol=1e-3)


def test_a_mission_no_retry_can_plan_is_one_failure_and_the_plan_is_kept():
    heightmap = make_terrain("step", height=1.0, start_x=1.5)  # a 1 m wall
    state = standing_state(heightmap, get_topology("nominal"))
    blc = TrajectoryOptimizationBLC(mission_retries=1, blc_params=WALL_BLC)
    context = _fixed(blc, heightmap, state, (0.3, 0.0, 0.0))
    simulator = Simulator(blc, context)
    simulator.Initialize()
    first = blc.GetOutputPort("plan").Eval(context)
    blc.GetInputPort("target").FixValue(context, np.array([2.0, 0.0, 0.0]))
    simulator.AdvanceTo(0.1)
    assert [s.success for s in blc.log.solves] == [True, False, False]
    assert [s.rung for s in blc.log.solves] == ["", "", "cycles+1"]
    # The refusal says why the first solve failed, then that the ladder planned nothing.
    reason = blc.log.failures[0].reason
    assert len(blc.log.failures) == 1 and reason.startswith(blc.log.solves[1].reason), reason
    assert reason.startswith("BLC: ") and "no rung of the ladder planned it (last: cycles+1: BLC" in reason
    assert blc.GetOutputPort("plan").Eval(context) is first
    with pytest.raises(QzError, match="mission_retries"):
        TrajectoryOptimizationBLC(mission_retries=-1)


def test_a_split_rung_plans_the_mission_in_two_halves_that_read_as_one_plan():
    blc = TrajectoryOptimizationBLC(ladder="split")
    context, _, _ = _second_mission_failing_first(blc, 1.1)
    assert [(s.success, s.rung) for s in blc.log.solves] == [(True, ""), (False, ""), (True, "split")]
    assert blc.log.retried == [1] and not blc.log.failures
    plan = blc.GetOutputPort("plan").Eval(context)
    assert isinstance(plan, ChainedPlan) and len(plan.parts) == 2
    half, rest = plan.parts
    # The nearer half ends halfway from the measured start (the fixed state input: x = 0); the
    # second starts where it ends, at its end time.
    np.testing.assert_allclose(half.base_position(half.end_time)[:2], [0.55, 0.0], atol=2e-3)
    assert rest.start_time == half.end_time and plan.end_time == rest.end_time
    for t in (half.end_time - 1e-6, half.end_time, half.end_time + 1e-6):
        np.testing.assert_allclose(plan.base_position(t), half.base_position(half.end_time), atol=1e-4)
        np.testing.assert_allclose(plan.foot_positions(t), half.foot_positions(half.end_time), atol=1e-4)
    np.testing.assert_allclose(plan.base_position(plan.end_time)[:2], [1.1, 0.0], atol=2e-3)
    # A foot standing through the junction touched down in the first half.
    for leg in range(6):
        assert plan.stance_start(leg, half.end_time + 0.05) < half.end_time


def test_ladder_rungs_are_checked_and_named():
    assert parse_ladder("cycles+1, split, split+2") == ("cycles+1", "split", "split+2")
    assert parse_ladder(None) == parse_ladder("") == ()
    assert parse_ladder("free,cycles+1") == ("free", "cycles+1")
    for bad in ("cycles", "split+9", "longer", "split,split", "short+1", "free+1"):
        with pytest.raises(QzError, match="ladder"):
            TrajectoryOptimizationBLC(ladder=bad)
    with pytest.raises(QzError, match="mission_retries"):
        TrajectoryOptimizationBLC(ladder="split", mission_retries=1)
    with pytest.raises(QzError, match="ladder_budget"):
        TrajectoryOptimizationBLC(ladder_budget=0)
