"""A* with CapPlanner's recovery (issue 38): a mission the BLC refuses is split, then its
target's surroundings are blocked and A* plans again from where the robot stands."""

import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from qz_drake.errors import QzError
from qz_drake.experiments.astar_baseline import AStarBaseline, AStarBaselineConfig, astar_route
from qz_drake.experiments.astar_recovery import BLOCK_RADIUS, AStarRecoverySequencer
from qz_drake.state_layout import make_state
from qz_drake.systems.mission_sequencer import split_route
from qz_drake.terrain import HeightMap

START, GOAL = (0.5, 2.5), (7.5, 2.5)


def _open_world():
    """8 m x 5 m of level ground: A*'s route runs straight along y = 2.5 m."""
    return HeightMap(np.zeros((101, 161)), 0.05, (0.0, 0.0))


class _Loop:
    """The sequencer alone under a Simulator, its inputs set by hand: the robot's state and
    the BLC's count of missions it could not plan (no plan ever arrives)."""

    def __init__(self, max_recoveries=4):
        self.baseline = AStarBaseline(_open_world(), AStarBaselineConfig(waypoint_spacing=1.0))
        route = self.baseline.route(START, GOAL)
        assert route.found
        self.first = split_route(START, route.waypoints, 1.0)
        self.system = AStarRecoverySequencer(targets=self.first, baseline=self.baseline, goal=GOAL,
                                             mission_length=1.0, max_recoveries=max_recoveries)
        self.simulator = Simulator(self.system)
        self.context = self.simulator.get_mutable_context()
        self.failed = 0
        self.system.GetInputPort("plan").FixValue(self.context, None)
        self.system.GetInputPort("robot_topology").FixValue(self.context, "nominal")
        self.system.GetInputPort("failed_missions").FixValue(self.context, [0.0])
        self.stand(*START)
        self.simulator.AdvanceTo(0.01)

    def stand(self, x, y, yaw=0.0):
        self.system.GetInputPort("state").FixValue(self.context, make_state([x, y, 0.3], [0.0, 0.0, yaw], np.zeros(18)))

    def refuse(self):
        """The BLC could not plan the current target: the count goes up, the sequencer answers."""
        self.failed += 1
        self.system.GetInputPort("failed_missions").FixValue(self.context, [float(self.failed)])
        self.simulator.AdvanceTo(self.context.get_time() + 0.06)

    def target(self):
        return np.asarray(self.system.GetOutputPort("target").Eval(self.context))


def test_a_refused_long_mission_is_split_then_its_target_blocked_and_a_route_found_round_it():
    loop = _Loop()
    first = np.asarray(loop.first[0][:3])
    assert loop.target() == pytest.approx(first)
    # A 1 m mission refused: the same way in two halves, the second ending where it did.
    loop.refuse()
    half = loop.target()
    assert half[:2] == pytest.approx((START[0] + 0.5 * (first[0] - START[0]), 2.5), abs=1e-6)
    assert loop.system.log.recoveries[-1][2] == "split"
    # The half refused too: the cells round it are blocked and A* plans from the robot.
    loop.refuse()
    assert loop.system.log.recoveries[-1][2] == "blocked" and loop.system.log.replans[-1][2]
    detour = loop.target()
    assert math.hypot(detour[0] - half[0], detour[1] - half[1]) > 0.2
    # The new route never enters the blocked disc (the planner's cells are inside it).
    body = np.asarray(loop.baseline.cost_map.body_cost)
    assert np.isinf(body).sum() > 50
    route = loop.baseline.route(START, GOAL)
    assert route.found
    assert np.min(np.hypot(route.path_xy[:, 0] - half[0], route.path_xy[:, 1] - half[1])) > BLOCK_RADIUS - 0.15
    assert len(loop.system.log.recoveries) == 2 and not loop.system.done
    counts = loop.system.counts()
    assert counts["tlc_recoveries"] == 2 and counts["unreachable"] == ""


def test_a_refusal_with_the_robot_off_the_map_is_a_reported_dead_end_not_a_crash():
    """A robot that walked past the map's edge (a Fig. 9 validation walk, session 52) has no A*
    route from where it stands: the walk is told why, as for a dead end."""
    loop = _Loop()
    route = loop.system._route_from((3.0, -0.6))  # 0.6 m beyond the map's lower edge
    assert not route.found and "start = (3.0, -0.6): off the map" in route.reason
    assert loop.system._route_from(START).found


def test_after_the_limit_the_goal_is_unreachable_and_the_robot_stands():
    loop = _Loop(max_recoveries=1)
    loop.refuse()  # the first is gone round (split)
    half = loop.target()
    loop.refuse()  # the second is one too many
    assert loop.system.done and "could not plan 2 missions" in loop.system.log.unreachable
    assert loop.system.counts()["unreachable"] == loop.system.log.unreachable
    # The refused target stays on the output: the BLC system, which does not solve one mission
    # twice, leaves the robot standing.
    assert loop.target() == pytest.approx(half)


def test_from_a_dead_end_astar_backs_out_to_where_the_last_mission_started_and_routes_from_there(straight_plan):
    """The robot walked its first mission; there the BLC refuses the next and, once its target
    is blocked, A* finds no way out of where the robot stands (closed in on every side): the
    robot backs out to where the walked mission started and A* routes from there, as CapPlanner
    does (qz_drake.planning.back_out); without back_out the goal is unreachable."""
    for back_out in (True, False):
        loop = _Loop()
        loop.system = AStarRecoverySequencer(targets=loop.first, baseline=loop.baseline, goal=GOAL, mission_length=1.0,
                                             back_out=back_out)
        loop.simulator = Simulator(loop.system)
        loop.context = loop.simulator.get_mutable_context()
        loop.system.GetInputPort("robot_topology").FixValue(loop.context, "nominal")
        loop.system.GetInputPort("failed_missions").FixValue(loop.context, [0.0])
        here = tuple(loop.first[0][:2])
        loop.system.GetInputPort("plan").FixValue(loop.context, straight_plan(START, here, 0.0, 1.0, z=0.3))
        loop.stand(*here)
        loop.simulator.AdvanceTo(1.2)  # the first mission walked, the second handed out
        assert loop.target()[:2] == pytest.approx(loop.first[1][:2])
        # Close the robot in: a ring of blocked discs round where it stands.
        for angle in np.linspace(0.0, 2 * np.pi, 16, endpoint=False):
            loop.baseline.block((here[0] + 0.5 * np.cos(angle), here[1] + 0.5 * np.sin(angle)), 0.25)
        assert not loop.baseline.route(here, GOAL).found
        loop.refuse()  # the 1 m mission: split
        loop.refuse()  # its half: blocked, and no route from here
        log = loop.system.log
        if not back_out:
            assert loop.system.done and log.unreachable.startswith("no route round") and log.back_outs == 0
            continue
        assert log.recoveries[-1][2] == "backed out" and log.back_outs == 1 and not loop.system.done
        assert loop.target() == pytest.approx((*START, 0.0))
        assert loop.system.counts()["tlc_back_outs"] == 1
        # The missions after it are A*'s route from the back-out stance round the ring to the goal.
        missions, _ = loop.context.get_abstract_state(0).get_value()
        assert missions[-1].target[:2] == pytest.approx(GOAL) and len(missions) >= 3
        route = np.array([m.target[:2] for m in missions[1:]])
        assert np.min(np.hypot(route[:, 0] - here[0], route[:, 1] - here[1])) > 0.5


def test_astar_route_is_the_baselines_route_and_bad_input_is_named():
    world = _open_world()
    a = astar_route(world, START, GOAL)
    b = AStarBaseline(world).route(START, GOAL)
    assert a.found and a.waypoints == b.waypoints
    with pytest.raises(QzError, match="block radius"):
        AStarBaseline(world).block((1.0, 1.0), 0.0)
    with pytest.raises(QzError, match="max_recoveries"):
        AStarRecoverySequencer(targets=a.waypoints, baseline=AStarBaseline(world), goal=GOAL, mission_length=1.0,
                               max_recoveries=-1)


def test_blocking_round_a_target_beside_the_robot_leaves_the_robot_a_way_out():
    """A refused short mission's target lies within the block radius of the robot: only the
    cells nearer the target than the robot are blocked, so A* still leaves from where it stands
    and goes round."""
    baseline = AStarBaseline(_open_world())
    robot, target = (3.0, 2.5), (3.4, 2.5)
    baseline.block(target, BLOCK_RADIUS, keep_clear=robot)
    route = baseline.route(robot, GOAL)
    assert route.found
    assert np.min(np.hypot(route.path_xy[:, 0] - target[0], route.path_xy[:, 1] - target[1])) > 0.15
    body = np.asarray(baseline.cost_map.body_cost)
    row, col = baseline.cost_map.cell(*robot)
    assert np.isfinite(body[row, col]) and np.isinf(body[baseline.cost_map.cell(*target)])


def test_in_a_walk_astar_goes_round_the_missions_the_blc_refuses_with_the_same_limit_as_capplanner():
    """End to end in Drake: a permissive A* (every step allowed) routes the robot past a
    0.45 m block; the BLC (30 iterations, as in Fig. 9) refuses the mission beside it, A* splits
    it, then blocks the refused target and plans round it from where the robot stands, and the
    BLC is given the new missions; after CapPlanner's limit of four the goal is unreachable and
    the walk says who gave up."""
    from qz_drake.config import ControllerConfig, RobotConfig, Scenario, SimulationConfig, TerrainConfig, Waypoint
    from qz_drake.experiments.astar_recovery import MAX_RECOVERIES, AStarRoute
    from qz_drake.simulation import build_walk, judge_walk_run, run_walk
    from qz_drake.trajopt.parameters import BlcParameters

    res = 0.05
    X, Y = np.meshgrid(res * np.arange(141), res * np.arange(121))
    world = HeightMap(np.where((X > 2.6) & (X < 3.4) & (Y > 1.4) & (Y < 2.6), 0.45, 0.0), res, (0.0, 0.0))
    start, goal = (0.8, 3.0), (6.0, 1.6)
    baseline = AStarBaseline(world, AStarBaselineConfig(max_step_height=1.0, max_slope_deg=89.0, safety_weight=0.0,
                                                        body_radius=0.3, waypoint_spacing=1.0))
    route = baseline.route(start, goal)
    scenario = Scenario(name="astar_recovery", terrain=TerrainConfig(kind="flat", region=[0, 7, 0, 6]),
                        robot=RobotConfig(initial_xy=list(start)), simulation=SimulationConfig(duration=60.0),
                        controller=ControllerConfig(kind="walk", planner="blc", mission_length=1.0,
                                                    route=[Waypoint(x=a, y=b, yaw=c, topology=t)
                                                           for a, b, c, t in route.waypoints]))
    built = build_walk(scenario, heightmap=world, route_source=AStarRoute(baseline, goal), mission_retries=0,
                       blc_params=BlcParameters(max_iterations=30, time_limit=30))
    run = run_walk(built, scenario, stop_on_failure=True)
    m = judge_walk_run(scenario, built, run).metrics
    log = built.missions.targets.log
    actions = [a for _, _, a in log.recoveries]
    assert len(actions) == MAX_RECOVERIES and actions[0] == "split" and "blocked" in actions
    assert any(found for _, _, found in log.replans)  # A* found routes round the refused targets
    # Every recovery's missions went to the BLC: the first route's planned ones, then one
    # solve per recovery at least.
    assert m["blc_solves"] >= m["missions"] + MAX_RECOVERIES and m["blc_failures"] == MAX_RECOVERIES + 1
    assert not m["success"] and "unreachable" in m["reasons"] and m["tlc_recoveries"] == MAX_RECOVERIES
    assert f"A* gave up after going round {MAX_RECOVERIES} missions the BLC could not plan" in m["reason"]
    # The task is a goal position: the heading A* arrives with is its own, never judged
    # against the first route's last segment (a route planned again comes in from elsewhere).
    assert m["final_yaw_error_deg"] == 0.0
    # Every mission of the walk with its outcome, as a capability model must predict it
    # (issue 37): the planned ones judged on their own stretch, the refused ones "no plan"
    # from where the robot stood, in the order they started.
    from qz_drake.capability.walk_missions import walk_mission_records

    records = walk_mission_records(built, run, judge_walk_run(scenario, built, run), scenario.success)
    outcomes = [r["outcome"] for r in records]
    assert outcomes.count("no_plan") == m["blc_failures"] and len(records) == m["blc_solves"]
    assert outcomes.count("walked") + outcomes.count("failed") == m["missions"]
    assert [r["start_time"] for r in records] == sorted(r["start_time"] for r in records)
    assert [r["index"] for r in records] == list(range(len(records)))
    for before, after in zip(records, records[1:]):
        if before["outcome"] == "walked":  # the next one starts where it ended
            assert np.hypot(*(np.subtract(after["start"][:2], before["target"][:2]))) < 0.15
    refused = [r for r in records if r["outcome"] == "no_plan"]
    assert all(r["reason"].startswith("blc_") and len(r["feet"]) == 6 for r in refused)
    # A refused one keeps the start its BLC was given: solved again from it (the refusal
    # benchmark, benchmarks/blc_refusals.py --replay), the same refusal.
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.systems.blc_plan import blc_mission_planner
    from qz_drake.systems.mission_sequencer import MissionStart

    given = refused[0]["blc_start"]
    start = MissionStart(time=0.0, xy_yaw=tuple(given["xy_yaw"]), feet_W=np.array(given["feet"]),
                         base_z=given["base_z"], roll_pitch=tuple(given["roll_pitch"]))
    planner = blc_mission_planner(world, DEFAULT_PARAMS, scenario.controller.timing,
                                  BlcParameters(max_iterations=30, time_limit=30))
    plan, reason = planner(start, tuple(refused[0]["target"]), refused[0]["topology"], 0.0)
    assert plan is None and reason[:200] == refused[0]["message"]
