"""CapPlanner's top-level controller as a system: plans around what the capability model calls
impossible, hands out missions one by one, replans at each mission start, says when the goal
is unreachable; and (slow) the whole CapPlanner walks a world in Drake."""

import math
import re

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource

from qz_drake.errors import QzError
from qz_drake.planning.capability_mdp import CapabilityMdpConfig
from qz_drake.planning.capability_planner import CapabilityVIPlanner
from qz_drake.state_layout import make_state
from qz_drake.terrain import HeightMap

START, GOAL = (-3.0, 0.0), (3.0, 0.0)


class WallModel:
    """A capability model stub: a move whose patch holds ground 0.15 m above the standing
    ground fails (p = 0.02), any other succeeds (0.97); turns 0.99."""

    def success(self, patches, feet, kind, topology, direction=None):
        patches = np.asarray(patches)
        if kind == "turn":
            return np.full(patches.shape[:-2], 0.99)
        return np.where(patches.max(axis=(-2, -1)) > 0.15, 0.02, 0.97)


def _world(enclosed: bool = False) -> HeightMap:
    """8 m x 7 m of 0.05 m cells (x -4..4, y -3..4); a 0.4 m wall across x 0-0.5 m from
    y = -3 to 1 m (the way round is north of it, where a move's 2 m x 2 m patch no longer
    sees the wall from y = 2 m on), or, enclosed, a wall all round the goal."""
    res = 0.05
    c = -4.0 + res / 2 + res * np.arange(160)
    r = -3.0 + res / 2 + res * np.arange(140)
    gx, gy = np.meshgrid(c, r)
    heights = np.zeros(gx.shape)
    if enclosed:
        ring = (np.abs(gx - GOAL[0]) < 1.2) & (np.abs(gy - GOAL[1]) < 1.2)
        inner = (np.abs(gx - GOAL[0]) < 0.9) & (np.abs(gy - GOAL[1]) < 0.9)
        heights[ring & ~inner] = 0.4
    else:
        heights[(gx >= 0.0) & (gx < 0.5) & (gy < 1.0)] = 0.4
    return HeightMap(heights, res, (float(c[0]), float(r[0])))


def _planner(heightmap):
    return CapabilityVIPlanner(model=WallModel(), heightmap=heightmap, goal=GOAL, start=(*START, 0.0),
                               mdp_config=CapabilityMdpConfig(topologies=["nominal"]))


def test_the_first_plan_goes_round_the_wall_and_reaches_the_goal():
    planner = _planner(_world())
    assert not planner.log.unreachable
    (t, start, count, probability), = planner.log.replans
    assert start == (*START, 0, "nominal") and count >= 3 and probability > 0.5
    builder = DiagramBuilder()
    system = builder.AddSystem(planner)
    state = builder.AddSystem(ConstantVectorSource(make_state([*START, 0.55], [0, 0, 0], np.zeros(18))))
    plan = builder.AddSystem(ConstantValueSource(AbstractValue.Make(None)))
    builder.Connect(state.get_output_port(), system.GetInputPort("state"))
    builder.Connect(plan.get_output_port(), system.GetInputPort("plan"))
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    sub = system.GetMyContextFromRoot(context)
    missions = system.GetOutputPort("guidance").Eval(sub)
    targets = np.array([m.target[:2] for m in missions])
    # The route passes north of the wall: every mission end within 1 m of it (in x) lies at
    # y >= 2 m, where the moves' patches no longer see it; the last one is the goal itself.
    near = np.abs(targets[:, 0] - 0.25) <= 1.0
    assert near.any() and np.all(targets[near, 1] >= 2.0 - 1e-9)
    np.testing.assert_allclose(targets[-1], GOAL)
    first = system.GetOutputPort("target").Eval(sub)
    np.testing.assert_allclose(first, missions[0].target)
    assert system.GetOutputPort("topology").Eval(sub) == "nominal"
    V, xs, ys = system.GetOutputPort("utility").Eval(sub)
    assert V.shape == (len(ys), len(xs))


def test_a_goal_behind_walls_is_reported_unreachable():
    planner = _planner(_world(enclosed=True))
    assert "chance of no fall" in planner.log.unreachable or "no path" in planner.log.unreachable
    assert planner.done


class LowWallModel(WallModel):
    """The wall can be crossed: a move whose patch sees it walks half the time."""

    def success(self, patches, feet, kind, topology, direction=None):
        p = super().success(patches, feet, kind, topology, direction)
        return np.where(p < 0.5, 0.5, p)


def test_where_the_policy_turns_in_place_the_most_probable_path_is_walked():
    """Round the goal a wall a move crosses half the time, and a failure worth -10 000: the MDP
    values turning in place for ever (about -100) above crossing, so its policy never reaches
    the goal; declining fails the task for certain, so the TLC walks the most probable path
    (its chance of no fall 0.25 > min_route_success) and says so in its log."""
    from qz_drake.planning.capability_mdp import most_likely_path, most_probable_path

    planner = CapabilityVIPlanner(model=LowWallModel(), heightmap=_world(enclosed=True), goal=GOAL,
                                  start=(*START, 0.0),
                                  mdp_config=CapabilityMdpConfig(topologies=["nominal"], failure_reward=-10_000.0))
    mdp, start = planner.mdp, planner.mdp.state(*planner.mdp.cell_of(*START), 0, "nominal")
    assert not most_likely_path(mdp, planner.solution, start)[1]
    steps, reaches, probability = most_probable_path(mdp, start)
    assert reaches and probability == np.prod([s.success for s in steps])
    crossings = [s for s in steps if s.success == 0.5]
    assert 1 <= len(crossings) <= 2 and probability > 0.2  # through the wall once, not round about
    assert not planner.log.unreachable and planner.log.most_probable == 1
    (_, _, count, predicted), = planner.log.replans
    assert count >= 2 and predicted == pytest.approx(probability)
    assert planner.counts()["tlc_most_probable"] == 1
    # Without a way through, still unreachable, with the reason; unless told to set out on any
    # path (min_route_success 0, as in the Fig. 9 experiment, where a declined task is failed).
    walled = _planner(_world(enclosed=True))
    assert walled.log.unreachable and walled.log.most_probable == 1 and walled.done
    bold = CapabilityVIPlanner(model=WallModel(), heightmap=_world(enclosed=True), goal=GOAL, start=(*START, 0.0),
                               mdp_config=CapabilityMdpConfig(topologies=["nominal"]), min_route_success=0.0)
    assert not bold.log.unreachable and bold.log.replans[0][2] >= 2 and bold.log.replans[0][3] < 0.01


def _standing(planner):
    """The planner alone in a simulator, its inputs fixed: the robot standing at the start,
    no plan yet, no failed mission."""
    from pydrake.systems.analysis import Simulator

    context = planner.CreateDefaultContext()
    planner.GetInputPort("state").FixValue(context, make_state([*START, 0.55], [0, 0, 0], np.zeros(18)))
    planner.GetInputPort("plan").FixValue(context, AbstractValue.Make(None))
    planner.GetInputPort("failed_missions").FixValue(context, np.zeros(1))
    planner.GetInputPort("robot_topology").FixValue(context, AbstractValue.Make("nominal"))
    simulator = Simulator(planner, context)
    simulator.Initialize()
    return simulator, context


def _blc_fails(planner, simulator, context, count):
    planner.GetInputPort("failed_missions").FixValue(context, np.full(1, float(count)))
    simulator.AdvanceTo(context.get_time() + 0.1)
    return planner.GetOutputPort("guidance").Eval(context)


def test_a_mission_the_blc_cannot_plan_is_split_then_its_action_forbidden_and_the_route_replanned():
    from qz_drake.planning.capability_mdp import step_state_action

    planner = _planner(_world())
    simulator, context = _standing(planner)
    first = planner.GetOutputPort("guidance").Eval(context)
    assert len(first[0].steps) >= 2  # a merged mission
    # The BLC could not plan it: the same actions come back one mission each.
    split = _blc_fails(planner, simulator, context, 1)
    assert [m.steps for m in split[:len(first[0].steps)]] == [[s] for s in first[0].steps]
    # The last of them ends where the failed mission did; the yaws continue without a jump.
    np.testing.assert_allclose(split[len(first[0].steps) - 1].target, first[0].target)
    yaws = np.array([0.0] + [m.target[2] for m in split])
    assert np.all(np.abs(np.diff(yaws)) <= np.pi + 1e-9)
    np.testing.assert_allclose(planner.GetOutputPort("target").Eval(context), split[0].target)
    assert planner.log.recoveries[-1][2] == "split" and len(planner.log.targets) == 1
    # It could not plan the single action either: the action is forbidden from that state and
    # the route replanned from where the robot stands; the new route does not start with it.
    failed_step = split[0].steps[0]
    s, a = step_state_action(planner.mdp, failed_step)
    replanned = _blc_fails(planner, simulator, context, 2)
    assert planner.log.recoveries[-1][2] == "forbade"
    assert planner.mdp.success[a, s] == 0.0 and planner.mdp.P[a][s, planner.mdp.failure_state] == 1.0
    assert replanned and step_state_action(planner.mdp, replanned[0].steps[0]) != (s, a)
    assert not planner.log.unreachable and not planner.done
    # The goal is still reached, round the wall.
    np.testing.assert_allclose(replanned[-1].target[:2], GOAL)


def test_the_route_in_the_context_is_shared_by_the_contexts_copies_and_replaced_not_changed():
    """The missions live in the context as a MissionQueue: Drake's copies of the state (every
    check, and Clone) share it, and a recovery replaces it, leaving a copy made before as it was."""
    from qz_drake.systems.mission_sequencer import MissionQueue

    planner = _planner(_world())
    simulator, context = _standing(planner)
    queue = context.get_abstract_state(0).get_value()
    assert isinstance(queue, MissionQueue)
    missions, index = queue
    assert index == 0 and isinstance(missions, tuple) and missions
    before = context.Clone()
    assert before.get_abstract_state(0).get_value() is queue
    _blc_fails(planner, simulator, context, 1)  # split: a new route
    after = context.get_abstract_state(0).get_value()
    assert after is not queue and after[0] != missions
    assert before.get_abstract_state(0).get_value() is queue and queue[0] == missions
    np.testing.assert_allclose(planner.GetOutputPort("target").Eval(before), missions[0].target)


@pytest.mark.parametrize("every_topology", [True, False])
def test_a_refused_move_is_forbidden_from_every_topology_the_robot_could_stand_in_there(every_topology):
    """The BLC refused a move in its topology from a cell and heading: the TLC does not come back
    to it from another topology's state (a switch there first), as it did before, a switch and
    a refusal at a time. By default (refused_in_every_topology) the same move in the other
    topologies is closed too (on the validation walks, 9 of 9 such retries were refused again); the
    turns from there stay allowed, and without it every other action does."""
    from qz_drake.planning.capability_mdp import MOTIONS, step_state_action

    planner = CapabilityVIPlanner(model=WallModel(), heightmap=_world(), goal=GOAL, start=(*START, 0.0),
                                  mdp_config=CapabilityMdpConfig(topologies=["nominal", "front_bend"]),
                                  refused_in_every_topology=every_topology)
    simulator, context = _standing(planner)
    while len(planner.GetOutputPort("guidance").Eval(context)[0].steps) > 1:  # split down to one action
        _blc_fails(planner, simulator, context, len(planner.log.recoveries) + 1)
    failed_step = planner.GetOutputPort("guidance").Eval(context)[0].steps[0]
    s, a = step_state_action(planner.mdp, failed_step)
    _blc_fails(planner, simulator, context, len(planner.log.recoveries) + 1)
    assert planner.log.recoveries[-1][2] == "forbade"
    ix, iy, k, _ = planner.mdp.unravel(s)
    n = len(MOTIONS)
    closed = [t * n + a % n for t in range(2)] if every_topology else [a]
    assert len(closed) == (2 if every_topology else 1)
    for t in ("nominal", "front_bend"):
        there = planner.mdp.state(ix, iy, k, t)
        for b in closed:
            assert planner.mdp.success[b, there] == 0.0 and planner.mdp.next_state[b, there] == planner.mdp.failure_state
        others = [b for b in range(planner.mdp.success.shape[0]) if b not in closed]
        assert (planner.mdp.success[others, there] > 0).all()


def test_after_max_recoveries_the_goal_is_unreachable_with_the_reason():
    planner = CapabilityVIPlanner(model=WallModel(), heightmap=_world(), goal=GOAL, start=(*START, 0.0),
                                  mdp_config=CapabilityMdpConfig(topologies=["nominal"]), max_recoveries=1)
    simulator, context = _standing(planner)
    split = _blc_fails(planner, simulator, context, 1)
    assert not planner.done
    assert _blc_fails(planner, simulator, context, 2) == []
    # The robot stands: the outputs hold the mission the BLC could not plan (which the BLC does
    # not solve again), not a new target at the robot's pose or in another topology.
    simulator.AdvanceTo(context.get_time() + 0.5)
    np.testing.assert_array_equal(planner.GetOutputPort("target").Eval(context), split[0].target)
    assert not np.allclose(split[0].target, [*START, 0.0])  # the robot stands at (START, yaw 0)
    assert planner.GetOutputPort("topology").Eval(context) == split[0].topology
    assert planner.done and planner.log.unreachable.startswith("the BLC could not plan 2 missions")
    # ... and says which: the mission it was last given.
    assert re.search(r"the last to \(x, y, yaw\) \[-?\d", planner.log.unreachable), planner.log.unreachable


def test_forbid_action_sends_the_action_to_failure_with_a_failures_reward():
    from qz_drake.planning.capability_mdp import forbid_action

    planner = _planner(_world())
    mdp = planner.mdp
    s, a = mdp.state(0, len(mdp.ys) - 1, 0, "nominal"), 0  # far from the wall
    assert mdp.success[a, s] > 0.9
    forbid_action(mdp, s, a)
    row = mdp.P[a][s].toarray().ravel()
    assert row[mdp.failure_state] == 1.0 and row.sum() == 1.0
    assert mdp.R[s, a] == -mdp.config.action_cost + mdp.config.failure_reward
    import pytest

    from qz_drake.errors import QzError
    with pytest.raises(QzError, match="state"):
        forbid_action(mdp, mdp.goal_state, a)


def _walk_one_mission(planner, simulator, context, start, end, plan):
    """The BLC plans the current mission (``plan``: conftest.StraightPlan) and the robot walks it
    from ``start`` to ``end``."""
    t0 = context.get_time()
    planner.GetInputPort("plan").FixValue(context, AbstractValue.Make(plan(start, end, t0, t0 + 1.0)))
    planner.GetInputPort("state").FixValue(context, make_state([*end, 0.55], [0, 0, 0], np.zeros(18)))
    simulator.AdvanceTo(t0 + 1.2)
    return planner.GetOutputPort("guidance").Eval(context)


def _dead_end(plan, back_out=True):
    """The robot walks one mission east, then the BLC refuses everything from where it stands."""
    planner = CapabilityVIPlanner(model=WallModel(), heightmap=_world(), goal=GOAL, start=(*START, 0.0),
                                  mdp_config=CapabilityMdpConfig(topologies=["nominal"]), max_recoveries=20,
                                  back_out=back_out)
    simulator, context = _standing(planner)
    here = (START[0] + 1.0, START[1])
    _walk_one_mission(planner, simulator, context, START, here, plan)
    failures = 0
    while not planner.done and not (planner.log.recoveries and planner.log.recoveries[-1][2] == "backed out"):
        failures += 1
        assert failures <= 12, planner.log.recoveries
        _blc_fails(planner, simulator, context, failures)
    return planner, simulator, context, here, failures


def test_from_a_dead_end_the_robot_backs_out_to_where_its_last_mission_started_and_plans_on(straight_plan):
    """The BLC refuses every move and turn from where the robot stands (a stance across a stair
    edge, session 38's validation walks): going round finds no way on, so the TLC hands out one
    mission back to where the last walked mission started (a stance the BLC planned from) and
    plans on from there, the dead end's actions still forbidden; without ``back_out`` the goal
    is unreachable there."""
    planner, simulator, context, here, failures = _dead_end(straight_plan)
    [back] = planner.GetOutputPort("guidance").Eval(context)
    assert back.back_out and back.steps == [] and planner.log.back_outs == 1
    np.testing.assert_allclose(back.target, (*START, 0.0), atol=1e-9)
    np.testing.assert_allclose(planner.GetOutputPort("target").Eval(context), back.target, atol=1e-9)
    assert not planner.done and not planner.log.unreachable
    assert planner.counts()["tlc_back_outs"] == 1
    # Every action from the dead end's state is forbidden.
    mdp = planner.mdp
    dead = mdp.state(*mdp.cell_of(*here), 0, "nominal")
    assert (mdp.success[:, dead] == 0.0).all()
    # The robot walks back; the TLC plans on from there, to the goal.
    missions = _walk_one_mission(planner, simulator, context, here, START, straight_plan)
    assert missions and not planner.done and not planner.log.unreachable
    np.testing.assert_allclose(missions[-1].target[:2], GOAL)
    # Without backing out, the same refusals leave the goal unreachable.
    stuck, *_ = _dead_end(straight_plan, back_out=False)
    assert stuck.done and "no path reaches the goal" in stuck.log.unreachable and stuck.log.back_outs == 0


def test_a_way_back_out_the_blc_refuses_ends_the_walk_with_the_reason(straight_plan):
    planner, simulator, context, here, failures = _dead_end(straight_plan)
    assert _blc_fails(planner, simulator, context, failures + 1) == []
    assert planner.done and planner.log.unreachable == "the BLC could not plan the way back out of a dead end"


class StanceModel(WallModel):
    """WallModel, and from a stance with a foot 0.1 m or more below the ground under the body
    every action but a right turn walks only 5 % of the time (the BLC refusing a stance across
    a step)."""

    def success(self, patches, feet, kind, topology, direction=None):
        from qz_drake.capability.patches import TURN_RIGHT

        p = super().success(patches, feet, kind, topology, direction)
        low = (np.asarray(feet)[..., 2] < -0.1).any(axis=-1)
        if kind == "turn":
            low = low & (np.asarray(direction) != TURN_RIGHT)
        return np.where(low, 0.05, p)


def test_the_first_moves_are_judged_from_the_stance_the_robot_stands_in(straight_plan):
    """The map assumes the topology's nominal footholds; at a replan the TLC judges the moves
    from the robot's cell by the stance it stands in (here a foot 0.25 m down, from which the
    model says only a right turn is planned), so it turns right first instead of left, round the
    wall; the next replan, from another stance, plans on the map's values again."""

    class FootDown(straight_plan):
        def foot_positions(self, t):
            feet = super().foot_positions(t).copy()
            feet[0, 2] -= 0.25
            return feet

    here = (START[0] + 1.0, START[1])
    firsts = {}
    for measured in (True, False):
        planner = CapabilityVIPlanner(model=StanceModel(), heightmap=_world(), goal=GOAL, start=(*START, 0.0),
                                      mdp_config=CapabilityMdpConfig(topologies=["nominal"]), measured_stance=measured)
        simulator, context = _standing(planner)
        missions = _walk_one_mission(planner, simulator, context, START, here, FootDown)
        firsts[measured] = missions[0].steps[0]
        assert missions and not planner.done
        if measured:
            mdp = planner.mdp
            s = mdp.state(*mdp.cell_of(*here), 0, "nominal")
            assert mdp.success[1, s] < 0.1 and mdp.stand[1, s] == 0.0  # a refusal from there is no retry
            # The robot turns and stands on its nominal footholds again: the map's values are back.
            turned = _walk_one_mission(planner, simulator, context, here, here, straight_plan)
            assert turned and mdp.success[1, s] > 0.9
    assert firsts[False].motion == "turn_left" and firsts[True].motion == "turn_right"


class DeadEndModel(WallModel):
    """WallModel, and from a stance with a foot 0.1 m or more below the ground under the body
    nothing walks (5 %): a dead end the model foretells."""

    def success(self, patches, feet, kind, topology, direction=None):
        p = super().success(patches, feet, kind, topology, direction)
        return np.where((np.asarray(feet)[..., 2] < -0.1).any(axis=-1), 0.05, p)


def test_a_dead_end_the_model_foretells_is_backed_out_of_without_a_refusal(straight_plan):
    """From a stance where the model predicts every move to fail, the TLC backs out at once
    (the walk's refusals are few: four, then the goal is unreachable) and never comes back to
    that cell and heading; the way back is not a refusal."""

    class FootDown(straight_plan):
        def foot_positions(self, t):
            feet = super().foot_positions(t).copy()
            feet[0, 2] -= 0.25
            return feet

    planner = CapabilityVIPlanner(model=DeadEndModel(), heightmap=_world(), goal=GOAL, start=(*START, 0.0),
                                  mdp_config=CapabilityMdpConfig(topologies=["nominal"]))
    simulator, context = _standing(planner)
    here = (START[0] + 1.0, START[1])
    [back] = _walk_one_mission(planner, simulator, context, START, here, FootDown)
    assert back.back_out and planner.log.predicted_dead_ends == planner.log.back_outs == 1
    np.testing.assert_allclose(back.target, (*START, 0.0), atol=1e-9)
    assert planner.log.recoveries == [] and not planner.done
    mdp = planner.mdp
    dead = mdp.state(*mdp.cell_of(*here), 0, "nominal")
    assert (mdp.next_state[:, dead] == mdp.failure_state).all()
    missions = _walk_one_mission(planner, simulator, context, here, START, straight_plan)
    assert missions and not missions[0].back_out and not planner.done
    np.testing.assert_allclose(missions[-1].target[:2], GOAL)


class LeaningModel(WallModel):
    """WallModel, and from a stance with a foot 0.1 m or more below the ground under the body
    every forward move walks ``factor`` times as often (turns as before)."""

    def __init__(self, factor: float = 1.0):
        self.factor = factor

    def success(self, patches, feet, kind, topology, direction=None):
        p = super().success(patches, feet, kind, topology, direction)
        if kind == "turn":
            return p
        return np.where((np.asarray(feet)[..., 2] < -0.1).any(axis=-1), p * self.factor, p)


def _wall_ahead() -> HeightMap:
    """10 m x 8 m of 0.05 m cells (x -4..6, y -4..4), a 0.4 m wall across x 1.75-2.25 m for
    |y| < 1.5 m: the way from (-3, 0) to (5, 0) goes round it, north or south."""
    res = 0.05
    c = -4.0 + res / 2 + res * np.arange(200)
    r = -4.0 + res / 2 + res * np.arange(160)
    gx, gy = np.meshgrid(c, r)
    heights = np.where((gx >= 1.75) & (gx < 2.25) & (np.abs(gy) < 1.5), 0.4, 0.0)
    return HeightMap(heights, res, (float(c[0]), float(r[0])))


def _first_mission_end(factor, hold_margin, foot_drop=0.0, shift=(0.0, 0.0)):
    """CapPlanner from (-3, 0) to (5, 0) round _wall_ahead; the first mission walked to its
    target (moved by ``shift``) with the nominal stance, one foot ``foot_drop`` lower. Returns
    (planner, the route held before the replan, the replan's missions)."""
    from qz_drake.capability import patches as P
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology

    heightmap = _wall_ahead()
    planner = CapabilityVIPlanner(model=LeaningModel(factor), heightmap=heightmap, goal=(5.0, 0.0),
                                  start=(-3.0, 0.0, 0.0), mdp_config=CapabilityMdpConfig(topologies=["nominal"]),
                                  hold_margin=hold_margin)
    route = list(planner.GetOutputPort("guidance").Eval(planner.CreateDefaultContext()))
    x, y, yaw = route[0].target
    x, y = x + shift[0], y + shift[1]
    feet = P.nominal_feet_W(heightmap, x, y, yaw, get_topology("nominal"), DEFAULT_PARAMS.foot_radius)
    feet[0, 2] -= foot_drop
    return planner, route[1:], planner.next_missions(1.0, x, y, yaw, "nominal", feet, route[1:])


def _targets(missions):
    return [tuple(np.round(m.target, 6)) for m in missions]


def test_path_value_is_the_policys_value_along_its_own_path_and_less_along_another():
    from qz_drake.planning.capability_mdp import most_likely_path, path_value

    planner, held, _ = _first_mission_end(1.0, None)
    mdp, solution = planner.mdp, planner.solution
    start = mdp.state(*mdp.cell_of(-3.0, 0.0), 0, "nominal")
    steps, reaches, _ = most_likely_path(mdp, solution, start)
    assert reaches
    epsilon = mdp.config.epsilon
    assert path_value(mdp, solution, steps) == pytest.approx(solution.V[start], abs=epsilon)
    # The held route from the first mission's end is the policy's there too.
    here = [s for m in held for s in m.steps]
    assert path_value(mdp, solution, here) == pytest.approx(solution.V[mdp.state(*mdp.cell_of(-2.0, 1.0), 1,
                                                                                  "nominal")], abs=epsilon)
    # Forbid the path's second action: walking it anyway is worth less than the policy's way round.
    from qz_drake.planning.capability_mdp import forbid_action, solve_capability_mdp, step_state_action

    forbid_action(mdp, *step_state_action(mdp, steps[1]))
    solution = solve_capability_mdp(mdp)
    assert path_value(mdp, solution, steps) < solution.V[start] - 10.0
    with pytest.raises(QzError, match="steps"):
        path_value(mdp, solution, [steps[0], steps[2]])


def test_a_replan_keeps_the_route_unless_the_new_one_is_worth_more_than_the_hold_margin():
    """At the first mission's end the robot stands with a foot 0.1 m low, from which forward
    moves walk 0.9 times as often: the policy would now turn and step east first (a gain of
    about 8 against a goal of 100). With ``hold_margin`` 20 the robot keeps its route; with
    0.5, or without holding (the paper's TLC), it changes; a stance from which forward moves
    walk 0.6 times as often is worth changing for even with 20. Without new information (the
    nominal stance) every setting keeps the route; an end off the route (another cell) is
    planned from anew."""
    planner, held, none = _first_mission_end(0.9, None, foot_drop=0.15)
    assert _targets(none) != _targets(held) and planner.log.route_decisions == [(1.0, "changed")]
    planner, held, kept = _first_mission_end(0.9, 20.0, foot_drop=0.15)
    assert _targets(kept) == _targets(held) and planner.log.route_decisions == [(1.0, "held")]
    assert planner.counts()["tlc_routes_held"] == 1 and planner.counts()["tlc_routes_changed"] == 0
    assert planner.log.replans[-1][2] == len(held)
    planner, held, changed = _first_mission_end(0.9, 0.5, foot_drop=0.15)
    assert _targets(changed) == _targets(none) and planner.log.route_decisions == [(1.0, "changed")]
    planner, held, changed = _first_mission_end(0.6, 20.0, foot_drop=0.15)
    assert _targets(changed) != _targets(held) and planner.log.route_decisions == [(1.0, "changed")]
    for margin in (None, 0.5, 20.0):
        planner, held, same = _first_mission_end(0.6, margin)
        assert _targets(same) == _targets(held) and planner.log.route_decisions == [(1.0, "same")]
    planner, held, moved = _first_mission_end(1.0, 20.0, shift=(1.0, 0.0))
    assert planner.log.route_decisions == [(1.0, "off route")] and moved and _targets(moved) != _targets(held)


def test_a_hold_margin_must_be_a_finite_number_at_least_zero():
    for bad in (-1.0, float("nan"), True, "2"):
        with pytest.raises(QzError, match="hold_margin"):
            _first_mission_end(1.0, bad)


@pytest.mark.parametrize("risk", [0.0, 0.5, 1.0])
def test_a_refusal_foretold_from_the_stance_is_weighed_as_the_map_weighs_refusals(risk):
    """From the robot's stance the model says the forward move walks 0.6 of the time and is
    planned 0.7: the 0.3 refused leaves the robot standing (the TLC goes round) but for the
    share plan_failure_risk counted as a fall, as on the rest of the map; restore_actions puts
    the map's values back."""
    from qz_drake.planning.capability_mdp import action_reward, restore_actions, set_stance

    planner = CapabilityVIPlanner(model=WallModel(), heightmap=_world(), goal=GOAL, start=(*START, 0.0),
                                  mdp_config=CapabilityMdpConfig(topologies=["nominal"], plan_failure_risk=risk))
    mdp = planner.mdp
    s = mdp.state(*mdp.cell_of(*START), 0, "nominal")
    before = (mdp.success[:, s].copy(), mdp.stand[:, s].copy(), mdp.R[s].copy())
    saved = set_stance(mdp, s, np.array([[0.6, 0.7, 0.0], [0.99, 1.0, 0.0], [0.95, 0.97, 0.0]]))
    assert mdp.success[0, s] == pytest.approx(0.6) and mdp.stand[0, s] == pytest.approx(0.3 * (1.0 - risk))
    assert mdp.stand[2, s] == pytest.approx(0.03 * (1.0 - risk))
    assert mdp.R[s, 0] == pytest.approx(action_reward(mdp.config, 0.6, 0.3 * (1.0 - risk), False, False))
    restore_actions(mdp, saved)
    for was, now in zip(before, (mdp.success[:, s], mdp.stand[:, s], mdp.R[s])):
        np.testing.assert_array_equal(was, now)


@pytest.mark.parametrize("cost", [0.0, 20.0])
def test_with_a_revisit_cost_a_replan_goes_on_somewhere_new_rather_than_back(cost):
    """Issue 54's routes that hold (session 53): validation walks on box fields went round the
    same few cells after each foreseen refusal until their time ran out. On open ground from
    x = -3 m to the goal at x = 3 m, a mission ended in the cell at (0, 0) and the next one back
    at (-1, 0): with a revisit cost the route from there goes round the cell it has been in; without,
    straight through it again."""
    from qz_drake.planning.guidance import route_ahead

    heightmap = HeightMap(np.zeros((140, 160)), 0.05, (-3.975, -2.975))
    planner = CapabilityVIPlanner(model=WallModel(), heightmap=heightmap, goal=GOAL, start=(*START, 0.0),
                                  mdp_config=CapabilityMdpConfig(topologies=["nominal"]), revisit_cost=cost)
    planner.next_missions(1.0, 0.0, 0.0, np.pi, "nominal", None, [])  # a mission ended at (0, 0), facing west
    ahead = route_ahead(planner.next_missions(2.0, -1.0, 0.0, 0.0, "nominal", None, []), 2.5)
    assert ahead[0] == (-1.0, 0.0)
    assert ((0.0, 0.0) in ahead) == (cost == 0.0)
    with pytest.raises(QzError, match="revisit_cost"):
        CapabilityVIPlanner(model=WallModel(), heightmap=heightmap, goal=GOAL, start=(*START, 0.0),
                            mdp_config=CapabilityMdpConfig(topologies=["nominal"]), revisit_cost=-1.0)


@pytest.mark.parametrize("shift", [0.0, 0.3])
def test_with_a_target_shift_a_mission_ends_clear_of_a_box_in_its_cell_and_the_last_at_the_goal(shift):
    """Issue 54 (session 54): the grid is anchored at the start, so a mission's cell centre may
    fall a few centimetres from a box's side. A 0.1 m box (the stub model walks over it) 5 cm
    north of the centre (-1, 0) on the straight route: with a shift the mission ending there
    ends south of it, in the same cell; the goal stays the goal."""
    res = 0.05
    c = -4.0 + res / 2 + res * np.arange(160)
    r = -3.0 + res / 2 + res * np.arange(140)
    gx, gy = np.meshgrid(c, r)
    heights = np.where((gx >= -1.3) & (gx < -0.7) & (gy >= 0.05) & (gy < 0.6), 0.1, 0.0)
    planner = CapabilityVIPlanner(model=WallModel(), heightmap=HeightMap(heights, res, (float(c[0]), float(r[0]))),
                                  goal=GOAL, start=(*START, 0.0),
                                  mdp_config=CapabilityMdpConfig(topologies=["nominal"]), target_shift=shift)
    missions = planner.next_missions(0.5, -3.0, 0.0, 0.0, "nominal", None, [])
    first = [m for m in missions if m.steps and m.steps[-1].x == -2.0][0]  # the move ending in cell (-1, 0)
    x, y, yaw = first.target
    assert yaw == 0.0 and planner.mdp.cell_of(x, y) == planner.mdp.cell_of(-1.0, 0.0)
    if shift:
        assert y < -0.2 and math.hypot(x + 1.0, y) <= shift + 1e-9
    else:
        assert (x, y) == (-1.0, 0.0)
    assert missions[-1].target[:2] == GOAL
    with pytest.raises(QzError, match="target_shift"):
        CapabilityVIPlanner(model=WallModel(), heightmap=HeightMap(heights, res, (float(c[0]), float(r[0]))),
                            goal=GOAL, start=(*START, 0.0), mdp_config=CapabilityMdpConfig(topologies=["nominal"]),
                            target_shift=0.6)
