"""The route check (qz_drake.planning.route_check): a route's next missions planned by the BLC
alone before they are handed out, and a refusal foreseen there gone round by both recovering
route sources before the robot walks anywhere."""

import math

import numpy as np
import pytest

from qz_drake.errors import QzError
from qz_drake.planning.route_check import Foreseen, RouteCheck, check_route_check
from qz_drake.systems.mission_sequencer import MissionStart


class RefusingCheck:
    """A route check that refuses every mission whose target lies within ``radius`` of
    ``place`` and plans every other; it records the routes it was shown."""

    horizon = 3
    solves = 0
    time_s = 0.0

    def __init__(self, place, radius=0.3):
        self.place, self.radius = place, radius
        self.routes = []

    def first_refused(self, start, missions, topology):
        self.routes.append([tuple(m.target) for m in missions])
        for i, m in enumerate(missions[:self.horizon]):
            if math.hypot(m.target[0] - self.place[0], m.target[1] - self.place[1]) <= self.radius:
                return Foreseen(i, tuple(m.target), m.topology, "refused")
        return None


def _start(x, y, yaw=0.0):
    return MissionStart(time=0.0, xy_yaw=(x, y, yaw), feet_W=np.zeros((6, 3)))


class RefusingMission(RefusingCheck):
    """A route check that refuses one mission: the one to ``target`` (x, y, yaw)."""

    def __init__(self, target):
        self.target = target
        self.routes = []

    def first_refused(self, start, missions, topology):
        self.routes.append([tuple(m.target) for m in missions])
        for i, m in enumerate(missions[:self.horizon]):
            if _same(m.target, self.target):
                return Foreseen(i, tuple(m.target), m.topology, "refused")
        return None


def _same(a, b):
    turn = (a[2] - b[2] + math.pi) % (2 * math.pi) - math.pi
    return math.hypot(a[0] - b[0], a[1] - b[1]) < 1e-6 and abs(turn) < 1e-6


def test_capplanner_goes_round_a_refusal_the_check_foresees_before_walking():
    """CapPlanner's first route goes straight east; the check refuses one of its moves: the
    route handed out no longer has it, no recovery is spent and the move stays forbidden."""
    from tests.planning.test_capability_planner import WallModel

    from qz_drake.planning.capability_mdp import CapabilityMdpConfig, step_state_action
    from qz_drake.planning.capability_planner import CapabilityVIPlanner
    from qz_drake.planning.guidance import MissionSplitConfig
    from qz_drake.terrain import HeightMap

    world = HeightMap(np.zeros((100, 160)), 0.05, (-4.0, -2.5))
    start, goal = (-3.0, 0.0), (3.0, 0.0)
    one_move = MissionSplitConfig(min_success=1.0)  # a mission per action

    def planner(check=None):
        return CapabilityVIPlanner(model=WallModel(), heightmap=world, goal=goal, start=(*start, 0.0),
                                   mdp_config=CapabilityMdpConfig(topologies=["nominal"]), split_config=one_move,
                                   route_check=check, check_start=None if check is None else _start(*start))

    plain = planner()
    route = plain._replan(0.0, *start, 0.0, "nominal")
    refused = route[2]
    assert len(refused.steps) == 1
    check = RefusingMission(refused.target)
    checked = planner(check)
    log = checked.log
    assert [f[3] for f in log.foreseen] == [2] and _same(log.foreseen[0][1], refused.target)
    assert not log.recoveries and not log.unreachable
    # The route handed out is the one the check planned last: without the refused move, to the goal.
    handed = check.routes[-1]
    assert not any(_same(t, refused.target) for t in handed[:check.horizon])
    assert handed[-1][:2] == pytest.approx(goal)
    assert log.targets[0][:3] == pytest.approx(handed[0])
    s, a = step_state_action(checked.mdp, refused.steps[0])
    assert checked.mdp.success[a, s] == 0.0
    counts = checked.counts()
    assert counts["tlc_foreseen_refusals"] == 1 and counts["tlc_recoveries"] == 0
    # Without a check, nothing is foreseen and the route keeps the move.
    assert plain.counts()["tlc_foreseen_refusals"] == 0 and "route_check_solves" not in plain.counts()


def test_astar_goes_round_a_refusal_the_check_foresees_before_walking():
    from tests.experiments.test_astar_recovery import GOAL, START, _open_world

    from qz_drake.experiments.astar_baseline import AStarBaseline, AStarBaselineConfig
    from qz_drake.experiments.astar_recovery import AStarRecoverySequencer
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.systems.mission_sequencer import split_route

    baseline = AStarBaseline(_open_world(), AStarBaselineConfig(waypoint_spacing=1.0))
    first = split_route(START, baseline.route(START, GOAL).waypoints, 1.0)
    refused = first[2][:2]
    check = RefusingCheck(refused)
    check.horizon = 4
    system = AStarRecoverySequencer(targets=first, baseline=baseline, goal=GOAL, mission_length=1.0,
                                    route_check=check, check_start=_start(*START), params=DEFAULT_PARAMS)
    log = system.log
    # As a refusal met: the 1 m mission is split in two first, then its second half's target
    # is blocked and A* routes again from the start.
    assert [f[3] for f in log.foreseen] == [2, 3] and not log.recoveries
    assert [r[2] for r in log.replans] == [True]
    handed = check.routes[-1]
    assert handed[-1][:2] == pytest.approx(GOAL)
    assert all(math.hypot(t[0] - refused[0], t[1] - refused[1]) > 0.3 for t in handed)
    assert system.counts()["tlc_foreseen_refusals"] == 2
    # A route source without the robot's parameters cannot check a route after a refusal.
    with pytest.raises(QzError, match="params"):
        AStarRecoverySequencer(targets=first, baseline=baseline, goal=GOAL, mission_length=1.0, route_check=check)


def test_the_blc_alone_plans_a_route_ahead_and_names_the_first_mission_it_refuses():
    """On level ground with a 0.4 m wall 2 m ahead: the check plans the first mission from the
    standing robot and refuses the one into the wall, from the first one's expected end."""
    from qz_drake.config import MissionTiming
    from qz_drake.experiments.astar_recovery import AStarMission
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology
    from qz_drake.scene import standing_state
    from qz_drake.systems.mission_sequencer import measured_start
    from qz_drake.terrain import HeightMap
    from qz_drake.capability.trials import TrialConfig, trial_blc_parameters

    res = 0.02
    xs = -1.5 + res * np.arange(250)
    heights = np.zeros((150, 250))
    heights[:, (xs >= 1.6) & (xs < 2.0)] = 0.4
    world = HeightMap(heights, res, (-1.5, -1.5))
    x0 = standing_state(world, get_topology("nominal", DEFAULT_PARAMS), (0.0, 0.0), 0.0, DEFAULT_PARAMS)
    check = RouteCheck(world, DEFAULT_PARAMS, MissionTiming(), trial_blc_parameters(TrialConfig()), ladder=(),
                       horizon=2)
    route = [AStarMission((0.5, 0.0, 0.0), "nominal"), AStarMission((1.5, 0.0, 0.0), "nominal")]
    start = measured_start(x0, 0.0, DEFAULT_PARAMS)
    assert check.first_refused(start, route[:1], "nominal") is None
    foreseen = check.first_refused(start, route, "nominal")
    assert foreseen is not None and foreseen.index == 1 and foreseen.reason
    assert check.solves == 3 and check.time_s > 0
    # A horizon of one mission sees only the first.
    one = RouteCheck(world, DEFAULT_PARAMS, MissionTiming(), trial_blc_parameters(TrialConfig()), horizon=1)
    assert one.first_refused(start, route, "nominal") is None
    # The chain stops at a topology change (a switch is planned from the standing robot).
    assert check.first_refused(start, [AStarMission((0.5, 0.0, 0.0), "hind_bend")], "nominal") is None


def test_a_bad_horizon_is_named():
    assert check_route_check(0) == 0 and check_route_check(3) == 3
    for bad in (-1, 1.5, True, "2"):
        with pytest.raises(QzError, match="route_check"):
            check_route_check(bad)
    with pytest.raises(QzError, match="horizon"):
        RouteCheck(None, None, None, None, horizon=0)
