"""The capability MDP (paper 000 II-E.2) on a synthetic map with two corridors through a wall,
one of which holds a low ridge that a stub capability model calls impossible."""

import dataclasses
import re

import numpy as np
import pytest

from qz_drake.errors import QzError
from qz_drake.planning.capability_mdp import (CapabilityMdpConfig, build_capability_mdp, plan, plan_on_map)
from qz_drake.capability.model import predict_map
from qz_drake.terrain import HeightMap

START, GOAL = (1.5, 5.5), (12.5, 5.5)


class StubModel:
    """CapabilityModel's ``success`` interface: a move fails (p = 0.02) when its patch holds
    anything higher than the topology's threshold above the standing ground, else p = 0.97;
    turns succeed with 0.99. Counts its calls."""

    def __init__(self, thresholds=None, default=0.05):
        self.thresholds, self.default, self.calls = dict(thresholds or {}), default, []

    def success(self, patches, feet, kind, topology, direction=None):
        patches = np.asarray(patches)
        assert np.shape(feet) == patches.shape[:-2] + (6, 3)
        self.calls.append((kind, topology, patches.shape[:-2]))
        if kind == "turn":
            assert direction is not None
            return np.full(patches.shape[:-2], 0.99)
        high = patches.max(axis=(-2, -1))
        return np.where(high > self.thresholds.get(topology, self.default), 0.02, 0.97)


@pytest.fixture(scope="module")
def corridors():
    """14 m x 12 m, 0.1 m cells; a 0.6 m wall at x 6-7 m with two 3 m openings: A at
    y 4-7 m on the straight line from start to goal, with a 0.08 m ridge at x 6.3-6.7 m, and
    B at y 9-12 m, flat."""
    res = 0.1
    x = 0.05 + res * np.arange(140)
    y = 0.05 + res * np.arange(120)
    X, Y = np.meshgrid(x, y)
    h = np.where((X > 6) & (X < 7), 0.6, 0.0)
    h[(X > 6) & (X < 7) & (((Y > 4) & (Y < 7)) | (Y > 9))] = 0.0
    h[(X > 6.3) & (X < 6.7) & (Y > 4) & (Y < 7)] = 0.08
    return HeightMap(h, res, (0.05, 0.05))


def crossing(plan_result):
    """y of the path's cells in the wall's column (x = 6.5 m)."""
    cells = plan_result.cells
    return cells[np.isclose(cells[:, 0], 6.5), 1]


def test_path_avoids_the_corridor_the_model_calls_impossible(corridors):
    result = plan(StubModel(), corridors, START, 0, GOAL, config=CapabilityMdpConfig(topologies=["nominal"]))
    assert result.reaches_goal and result.solution.converged
    ys = crossing(result)
    assert len(ys) and np.all(ys > 9)  # through B, not the ridge of A
    assert result.success_probability > 0.4
    assert np.allclose(result.cells[0], START) and np.allclose(result.cells[-1], GOAL)
    # Each network saw the whole map in one batched call.
    model = StubModel()
    plan(model, corridors, START, 0, GOAL, config=CapabilityMdpConfig(topologies=["nominal"]))
    assert sorted(c[0] for c in model.calls) == ["diagonal", "orthogonal", "turn"]


def test_path_takes_the_short_corridor_when_the_model_allows_it(corridors):
    result = plan(StubModel(default=0.1), corridors, START, 0, GOAL, config=CapabilityMdpConfig(topologies=["nominal"]))
    assert result.reaches_goal
    ys = crossing(result)
    assert len(ys) and np.all((ys > 4) & (ys < 7))
    # The straight line: eleven forward moves along heading 0, no turn.
    assert [s.motion for s in result.steps] == ["forward"] * 11


def test_topology_change_where_it_pays(corridors, tmp_path):
    model = StubModel(thresholds={"front_bend": 0.1})  # only front_bend climbs the ridge
    capability_map = predict_map(model, corridors, ["nominal", "front_bend"])
    cheap = plan_on_map(capability_map, START, 0, GOAL, config=CapabilityMdpConfig(topology_change_cost=2.0))
    assert cheap.reaches_goal and cheap.topology_changes >= 1
    ys = crossing(cheap)
    assert np.all((ys > 4) & (ys < 7))
    ridge_steps = [s for s in cheap.steps if s.motion == "forward" and 5.0 < s.x < 7.0]
    assert ridge_steps and all(s.action_topology == "front_bend" for s in ridge_steps)
    from qz_drake.capability.plots import plot_plan
    assert plot_plan(corridors, cheap, tmp_path / "plan.png").stat().st_size > 1000
    # A change dearer than the detour: the robot stays nominal and goes round through B.
    dear = plan_on_map(capability_map, START, 0, GOAL, config=CapabilityMdpConfig(topology_change_cost=60.0))
    assert dear.reaches_goal and dear.topology_changes == 0 and np.all(crossing(dear) > 9)


def test_mdp_structure_and_values(corridors):
    capability_map = predict_map(StubModel(), corridors, ["nominal"])
    mdp = build_capability_mdp(capability_map, GOAL)
    S = mdp.failure_state + 1
    assert len(mdp.P) == 3 and all(m.shape == (S, S) for m in mdp.P)
    for m in mdp.P:
        assert np.allclose(np.asarray(m.sum(axis=1)).ravel(), 1.0)
    # Forward off the grid always fails; the absorbing states stay put.
    s = mdp.state(0, 3, 4, "nominal")  # west edge, heading west
    assert mdp.success[0, s] == 0.0 and mdp.P[0][s, mdp.failure_state] == 1.0
    assert mdp.P[1][mdp.goal_state, mdp.goal_state] == 1.0
    # Next to the goal, facing it: forward reaches the goal state with the goal's reward.
    s = mdp.state(11, 5, 0, "nominal")
    assert mdp.next_state[0, s] == mdp.goal_state
    assert mdp.R[s, 0] == pytest.approx(-1.0 + 0.97 * 100.0 - 0.03 * 100.0)
    result = plan_on_map(capability_map, START, 0, GOAL)
    utility = result.utility_map()
    assert utility.shape == (12, 14)
    assert utility[5, 11] > utility[5, 8] > utility[5, 1]
    # The start in the goal cell has arrived.
    here = plan_on_map(capability_map, GOAL, 2, GOAL)
    assert here.reaches_goal and here.steps == []


def test_errors_name_the_field(corridors):
    capability_map = predict_map(StubModel(), corridors, ["nominal"])
    with pytest.raises(QzError, match="goal"):
        build_capability_mdp(capability_map, (30.0, 5.0))
    with pytest.raises(QzError, match="start"):
        plan_on_map(capability_map, (-3.0, 1.0), 0, GOAL)
    with pytest.raises(QzError, match="capability_mdp.discount"):
        build_capability_mdp(capability_map, GOAL, CapabilityMdpConfig(discount=1.0))
    with pytest.raises(QzError, match="start_topology"):
        plan_on_map(capability_map, START, 0, GOAL, start_topology="split_up")


def test_topology_changes_only_where_the_robot_can_make_them(corridors):
    """A topology change is given no success where the ground is not level (switchable_cells:
    a 15 deg ramp is not, flat ground is); with changes allowed only near the start, the path
    that climbs the ridge in front_bend switches there, and with none allowed it stays nominal
    and goes round."""
    from qz_drake.planning.capability_mdp import switchable_cells

    x = corridors.origin[0] + corridors.resolution * np.arange(corridors.heights.shape[1])
    ramp = np.broadcast_to(np.tan(np.radians(15)) * np.clip(x - 3.0, 0.0, 3.0), corridors.heights.shape)
    tilted = HeightMap(np.array(ramp), corridors.resolution, corridors.origin)
    xs, ys = 0.5 + np.arange(14.0), 0.5 + np.arange(12.0)
    mask = switchable_cells(tilted, xs, ys)
    assert mask[:, xs < 2.2].all() and not mask[:, (xs > 3.8) & (xs < 5.2)].any()
    assert mask[:, xs > 6.8].all()  # level again on top

    model = StubModel(thresholds={"front_bend": 0.1})  # only front_bend climbs the ridge
    capability_map = predict_map(model, corridors, ["nominal", "front_bend"], anchor=START)
    near_start = np.zeros((len(capability_map.ys), len(capability_map.xs)), dtype=bool)
    near_start[:, capability_map.xs < 2.2] = True
    result = plan_on_map(capability_map, START, 0, GOAL, switchable=near_start)
    assert result.reaches_goal and result.topology_changes >= 1
    for step in result.steps:
        if step.action_topology != step.topology:
            assert step.x < 2.2, step
    assert np.all((crossing(result) > 4) & (crossing(result) < 7))  # over the ridge, in front_bend
    nowhere = plan_on_map(capability_map, START, 0, GOAL, switchable=np.zeros_like(near_start))
    assert nowhere.reaches_goal and nowhere.topology_changes == 0 and np.all(crossing(nowhere) > 9)


class SharingStub(StubModel):
    """A StubModel that also says which share of each network's failures were the BLC's."""

    SHARES = {"orthogonal": 0.5, "diagonal": 0.7, "turn": 0.9}

    def plan_failure_share(self, topology, kind):
        return self.SHARES[kind]


def test_planning_failures_leave_the_robot_standing(corridors):
    """A failure is split by the model's measured share: the BLC found no plan (the robot stays
    in its state at plan_failure_cost) or the walk failed (the absorbing failure state); off
    the grid and refused topology changes fail outright."""
    from qz_drake.planning.capability_mdp import forbid_action

    capability_map = predict_map(SharingStub(), corridors, ["nominal", "front_bend"], anchor=START)
    assert np.allclose(capability_map.plan_failure_share, [[0.5, 0.7, 0.9]] * 2)
    switchable = np.ones((len(capability_map.ys), len(capability_map.xs)), dtype=bool)
    switchable[:, 0] = False
    mdp = build_capability_mdp(capability_map, GOAL, CapabilityMdpConfig(plan_failure_cost=3.0), switchable)
    for m in mdp.P:
        assert np.allclose(np.asarray(m.sum(axis=1)).ravel(), 1.0)
    fail = mdp.failure_state
    # Heading 0: the orthogonal network's share; heading 1: the diagonal one's; turns: 0.9.
    s0, s1 = mdp.state(2, 5, 0, "nominal"), mdp.state(2, 5, 1, "nominal")
    assert mdp.P[0][s0, s0] == pytest.approx(0.03 * 0.5) and mdp.P[0][s0, fail] == pytest.approx(0.03 * 0.5)
    assert mdp.P[0][s1, s1] == pytest.approx(0.03 * 0.7) and mdp.P[0][s1, fail] == pytest.approx(0.03 * 0.3)
    assert mdp.P[1][s0, s0] == pytest.approx(0.01 * 0.9) and mdp.P[1][s0, fail] == pytest.approx(0.01 * 0.1)
    assert mdp.R[s0, 0] == pytest.approx(-1.0 - 0.015 * 100.0 - 0.015 * 3.0)
    # Off the grid, and a topology change where none can be made: no standing, only failure.
    edge = mdp.state(0, 3, 4, "nominal")
    assert mdp.P[0][edge, edge] == 0.0 and mdp.P[0][edge, fail] == 1.0
    refused = mdp.state(0, 3, 0, "nominal")
    change = mdp.topologies.index("front_bend") * 3  # forward in front_bend
    assert mdp.P[change][refused, refused] == 0.0 and mdp.P[change][refused, fail] == 1.0
    # The config's share overrides the model's; 0 is the terminal reading.
    terminal = build_capability_mdp(capability_map, GOAL, CapabilityMdpConfig(plan_failure_share=0.0))
    assert terminal.P[0][s0, s0] == 0.0 and terminal.P[0][s0, fail] == pytest.approx(0.03)
    # Forbidding an action, twice, leaves it certain failure and every row stochastic.
    for s in (s0, mdp.state(3, 5, 0, "nominal")):
        forbid_action(mdp, s, 0)
        assert mdp.P[0][s, fail] == 1.0 and mdp.P[0][s, s] == 0.0 and mdp.stand[0, s] == 0.0
    assert np.allclose(np.asarray(mdp.P[0].sum(axis=1)).ravel(), 1.0)
    with pytest.raises(QzError, match="capability_mdp.plan_failure_share"):
        build_capability_mdp(capability_map, GOAL, CapabilityMdpConfig(plan_failure_share=1.5))


class FlatStub(StubModel):
    """Every move p = 0.95, every turn 0.99."""

    def success(self, patches, feet, kind, topology, direction=None):
        return np.full(np.shape(patches)[:-2], 0.99 if kind == "turn" else 0.95)


def test_a_long_route_reaches_the_goal_when_planning_failures_are_not_the_end():
    """On a 160 m corridor of moves with p = 0.95 (157 moves to the goal), a route's chance to
    arrive is 0.95^157: with every failure the end, the start's value is the failure's to
    epsilon and the greedy path loops near the start; with 80 % of failures leaving the robot
    standing (the trials' share), the values still point at the goal and the path arrives."""

    length = 160.0
    heightmap = HeightMap(np.zeros((30, int(length / 0.1))), 0.1, (0.05, 0.05))
    capability_map = predict_map(FlatStub(), heightmap, ["nominal"], anchor=(1.5, 1.5))
    goal = (length - 1.5, 1.5)
    # The 20 m world's discount and costs (scale_to_grid off), with every failure terminal.
    terminal = plan_on_map(capability_map, (1.5, 1.5), 0, goal,
                           config=CapabilityMdpConfig(plan_failure_share=0.0, scale_to_grid=False))
    assert not terminal.reaches_goal
    standing = plan_on_map(capability_map, (1.5, 1.5), 0, goal,
                           config=CapabilityMdpConfig(plan_failure_share=0.8, scale_to_grid=False))
    assert standing.reaches_goal and [s.motion for s in standing.steps] == ["forward"] * 157
    # Every move planned and walked at once: 0.95^157; no move ending the walk: (1 - 0.05 * 0.2)^157.
    assert standing.success_probability == pytest.approx(0.95 ** 157)
    assert standing.fall_free_probability == pytest.approx(0.99 ** 157)
    assert all(s.stand == pytest.approx(0.04) and s.fall == pytest.approx(0.01) for s in standing.steps)
    row = standing.utility_map()[1, :-2]
    assert np.all(np.diff(row) > 0)  # every cell nearer the goal is worth more


def test_on_a_larger_map_the_discount_and_costs_scale_so_that_the_goal_still_counts():
    """A 300 m corridor (297 moves of p = 0.95, 80 % of failures leaving the robot standing): with
    the 20 m world's discount and costs the route costs more than a fall and the path stops near
    the start; scaled to the grid (k = 7.6) it walks to the goal."""

    length = 300.0
    heightmap = HeightMap(np.zeros((30, int(length / 0.1))), 0.1, (0.05, 0.05))
    capability_map = predict_map(FlatStub(), heightmap, ["nominal"], anchor=(1.5, 1.5))
    goal, config = (length - 1.5, 1.5), CapabilityMdpConfig(plan_failure_share=0.8)
    unscaled = plan_on_map(capability_map, (1.5, 1.5), 0, goal, config=dataclasses.replace(config, scale_to_grid=False))
    assert not unscaled.reaches_goal and len(unscaled.steps) < 20
    scaled = plan_on_map(capability_map, (1.5, 1.5), 0, goal, config=config)
    assert scaled.reaches_goal and [s.motion for s in scaled.steps] == ["forward"] * 297
    k = (len(capability_map.xs) + len(capability_map.ys)) / 40
    assert k > 7
    assert scaled.mdp.config.discount == pytest.approx(1 - 0.01 / k)
    assert scaled.mdp.config.action_cost == pytest.approx(1 / k)
    # A grid of the 20 m world's size or smaller keeps the config as it is.
    assert CapabilityMdpConfig().for_grid(20, 20) == CapabilityMdpConfig()


def test_policy_evaluation_reaches_value_iterations_fixed_point_in_fewer_iterations(corridors):
    """Valuing each greedy policy (policy iteration's step) between improvements: the same Q as
    Eq. 9 iterated alone, to within epsilon, the same policy up to ties, in under half the
    iterations on this 14 m map (39 against 97; on 100 m x 100 m 51 against 756)."""
    from qz_drake.planning.capability_mdp import solve_capability_mdp

    capability_map = predict_map(SharingStub(), corridors, ["nominal", "front_bend"])
    evaluated = solve_capability_mdp(build_capability_mdp(capability_map, GOAL, CapabilityMdpConfig(epsilon=1e-3)))
    alone = solve_capability_mdp(build_capability_mdp(capability_map, GOAL,
                                                      CapabilityMdpConfig(epsilon=1e-3, policy_evaluation=False)))
    assert evaluated.converged and alone.converged
    assert np.max(np.abs(evaluated.Q - alone.Q)) < 1e-3
    # The same choices up to ties (two topologies the stub rates alike, turns either way).
    states = np.arange(len(alone.V))
    assert np.all(alone.Q[states, evaluated.policy] >= alone.V - 1e-3)
    assert evaluated.iterations * 2 < alone.iterations


def test_the_solver_answers_the_same_on_one_thread_or_two(corridors, monkeypatch):
    """The solver's loops over the states split over the free cores (QZ_TORCH_THREADS sets how
    many): the values, policy and Q are the same to the bit."""
    from qz_drake.planning.capability_mdp import solve_capability_mdp

    capability_map = predict_map(SharingStub(), corridors, ["nominal", "front_bend"])
    solutions = []
    for threads in ("1", "2"):
        monkeypatch.setenv("QZ_TORCH_THREADS", threads)
        solutions.append(solve_capability_mdp(build_capability_mdp(capability_map, GOAL, CapabilityMdpConfig())))
    one, two = solutions
    assert one.iterations == two.iterations
    for a, b in ((one.V, two.V), (one.Q, two.Q), (one.policy, two.policy)):
        np.testing.assert_array_equal(a, b)


def test_policy_evaluations_are_bounded_then_value_iteration_finishes(corridors, monkeypatch):
    """Past MAX_EVALUATIONS the solver iterates Eq. 9 alone, which always converges: with a bound
    of 2 it still reaches the same values."""
    from qz_drake.planning import capability_mdp as mdp_module

    capability_map = predict_map(SharingStub(), corridors, ["nominal"])
    config = CapabilityMdpConfig(epsilon=1e-3)
    full = mdp_module.solve_capability_mdp(build_capability_mdp(capability_map, GOAL, config))
    monkeypatch.setattr(mdp_module, "MAX_EVALUATIONS", 2)
    bounded = mdp_module.solve_capability_mdp(build_capability_mdp(capability_map, GOAL, config))
    assert bounded.converged and bounded.iterations > full.iterations
    assert np.max(np.abs(bounded.Q - full.Q)) < 1e-3


def test_after_a_planning_failure_the_robot_chooses_among_the_other_actions(corridors):
    """The BLC is deterministic, so the MDP does not count on retrying what it could not plan:
    the solver's Q is the fixed point of Q(s, a) = r + gamma (P V without the stay + q max_{b != a}
    Q(s, b)), and it is never above a plain self-loop's value (which would count on the retry)."""
    from qz_drake.planning.capability_mdp import solve_capability_mdp
    from qz_drake.planning.value_iteration import value_iteration

    mdp = build_capability_mdp(predict_map(SharingStub(), corridors, ["nominal"]), GOAL,
                               CapabilityMdpConfig(epsilon=1e-6))
    solution = solve_capability_mdp(mdp)
    assert solution.converged
    Q = solution.Q.T  # (A, S)
    V = Q.max(axis=0)
    other = np.empty_like(Q)
    for a in range(Q.shape[0]):
        other[a] = np.delete(Q, a, axis=0).max(axis=0)
    stacked = np.vstack([(m @ V) for m in mdp.P])  # includes the stay's q V(s)
    expected = mdp.R.T + mdp.config.discount * (stacked + mdp.stand * (other - V))
    assert np.allclose(Q, expected, atol=1e-4)
    assert mdp.stand.max() > 0.01
    looping = value_iteration(mdp.P, mdp.R, mdp.config.discount, epsilon=1e-6, max_iter=mdp.config.max_iter)
    assert np.all(solution.V <= looping.V + 1e-4)
    # Where a planning failure is likely and the other actions are worse, the retry is what a
    # self-loop overvalues.
    assert np.max(looping.V - solution.V) > 0.1
    # Without planning failures it is Eq. 9's value iteration.
    terminal = build_capability_mdp(predict_map(SharingStub(), corridors, ["nominal"]), GOAL,
                                    CapabilityMdpConfig(plan_failure_share=0.0, epsilon=0.01))
    assert np.allclose(solve_capability_mdp(terminal).V,
                       value_iteration(terminal.P, terminal.R, 0.99, epsilon=0.01, max_iter=5000).V)


def test_a_factored_model_says_per_state_which_failures_leave_the_robot_standing():
    """With a two-output model's P(the BLC plans it) in the map, the stay is 1 - p_plan of that
    state and action (not a share per network): of two moves with the same success 0.42, the
    one the BLC usually cannot plan (p_plan 0.45) mostly leaves the robot standing, the one it
    plans and then fails (p_plan 0.95, a leg on an obstacle) mostly ends the walk."""
    from qz_drake.capability.model import CapabilityMap

    nx, ny = 6, 3
    forward = np.full((1, 8, ny, nx), 0.97)
    turn = np.full((1, 8, ny, nx), 0.99)
    plan = np.full((1, 8, ny, nx), 0.99)
    forward[0, 0, 1, 2], plan[0, 0, 1, 2] = 0.42, 0.45
    forward[0, 0, 1, 3], plan[0, 0, 1, 3] = 0.42, 0.95
    capability_map = CapabilityMap(xs=0.5 + np.arange(nx), ys=0.5 + np.arange(ny), topologies=("nominal",),
                                   forward=forward, turn_left=turn, turn_right=turn.copy(),
                                   plan_failure_share=np.array([[0.8, 0.8, 0.8]]), forward_plan=plan,
                                   turn_left_plan=plan.copy(), turn_right_plan=plan.copy())
    mdp = build_capability_mdp(capability_map, (5.5, 1.5))
    assert mdp.plan_failure_source == "model, per state"
    blc, obstacle = mdp.state(2, 1, 0, "nominal"), mdp.state(3, 1, 0, "nominal")
    assert mdp.stand[0, blc] == pytest.approx(0.55) and mdp.P[0][blc, mdp.failure_state] == pytest.approx(0.03)
    assert mdp.stand[0, obstacle] == pytest.approx(0.05)
    assert mdp.P[0][obstacle, mdp.failure_state] == pytest.approx(0.53)
    # A fixed share in the config overrides the model's per-state view.
    fixed = build_capability_mdp(capability_map, (5.5, 1.5), CapabilityMdpConfig(plan_failure_share=0.5))
    assert fixed.plan_failure_source == "config" and fixed.stand[0, obstacle] == pytest.approx(0.29)
    # plan_failure_risk counts that share of the predicted planning failures as falls: at 0.5
    # half of the 0.55 stay moves to the failure state, at 1 every failure ends the walk.
    half = build_capability_mdp(capability_map, (5.5, 1.5), CapabilityMdpConfig(plan_failure_risk=0.5))
    assert half.stand[0, blc] == pytest.approx(0.275)
    assert half.P[0][blc, half.failure_state] == pytest.approx(0.03 + 0.275)
    assert half.R[blc, 0] < mdp.R[blc, 0]  # the riskier move is worth less
    full = build_capability_mdp(capability_map, (5.5, 1.5), CapabilityMdpConfig(plan_failure_risk=1.0))
    assert not full.stand.any() and full.P[0][blc, full.failure_state] == pytest.approx(0.58)
    with pytest.raises(QzError, match=r"capability_mdp.plan_failure_risk.*1.5"):
        build_capability_mdp(capability_map, (5.5, 1.5), CapabilityMdpConfig(plan_failure_risk=1.5))


def test_no_topology_change_beside_an_obstacle_within_the_legs_reach():
    """A 0.13 m box 0.5 m from a cell centre hardly moves the ground's roughness under the body
    (the 0.7 m disc) but stands in the legs' way when they swing to the new footholds."""
    from qz_drake.planning.capability_mdp import switchable_cells

    res = 0.05
    x = res / 2 + res * np.arange(120)
    X, Y = np.meshgrid(x, x)
    h = np.where((np.abs(X - 3.5) < 0.1) & (np.abs(Y - 3.0) < 0.1), 0.13, 0.0)
    heightmap = HeightMap(h, res, (res / 2, res / 2))
    xs, ys = np.array([3.0, 1.0, 4.3]), np.array([3.0])  # the box 0.5, 2.5 and 0.8 m away
    assert switchable_cells(heightmap, xs, ys).tolist() == [[False, True, False]]
    assert switchable_cells(heightmap, xs, ys, CapabilityMdpConfig(switch_max_step=0.2)).tolist() == [[True] * 3]


def test_a_greedy_policy_is_valued_exactly_along_its_chains_and_cycles():
    """The policy evaluation's compiled solve of V(s) = r(s) + gamma (p V(n(s)) + q Q_b(s)) on
    a random one-successor graph (chains into cycles of every length, self-loops, absorbing
    states), against a dense linear solve of the same equations."""
    from qz_drake.planning.capability_mdp import _kernels

    rng = np.random.default_rng(3)
    A, S, absorbing = 3, 400, 2
    grid = S - absorbing
    success = np.zeros((A, S))
    success[:, :grid] = rng.uniform(0.2, 1.0, (A, grid))
    stand = np.zeros((A, S))
    stand[:, :grid] = rng.uniform(0.0, 1.0, (A, grid)) * (1.0 - success[:, :grid])
    r = rng.normal(0.0, 1.0, (A, S))
    r[:, grid:] = 0.0
    next_state = rng.integers(0, S, (A, S))
    next_state[:, :40] = (np.arange(40) + 1) % 40  # one long cycle
    next_state[:, 40:45] = np.arange(40, 45)  # self-loops
    next_state[:, grid:] = np.arange(grid, S)
    best, runner_up = rng.integers(0, A, S), rng.integers(0, A, S)
    runner_up = np.where(runner_up == best, (best + 1) % A, runner_up)
    V_old = rng.normal(0.0, 5.0, S)
    gamma = 0.97

    state_major = [np.ascontiguousarray(x.T) for x in (success, stand, r, next_state)]
    values, second = _kernels().greedy_values(*state_major, best, runner_up, V_old, gamma, grid)

    states = np.arange(grid)
    a, b = best[:grid], runner_up[:grid]
    # V(s) = r_a + gamma (p_a V(n_a) + q_a (r_b + gamma (p_b V_old(n_b) + q_b V(s)))).
    M = np.eye(S)
    rhs = np.zeros(S)
    M[states, next_state[a, states]] -= gamma * success[a, states]
    M[states, states] -= gamma * gamma * stand[a, states] * stand[b, states]
    rest_b = r[b, states] + gamma * success[b, states] * V_old[next_state[b, states]]
    rhs[:grid] = r[a, states] + gamma * stand[a, states] * rest_b
    expected = np.linalg.solve(M, rhs)
    np.testing.assert_allclose(values, expected, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(second[:grid], rest_b + gamma * stand[b, states] * expected[:grid], rtol=1e-10)
    assert np.all(values[grid:] == 0.0)


def _open_ground_route(nominal: float, split_up: float, spread, **config):
    """The plan across 12 x 3 cells of open ground in two topologies whose forward moves succeed
    with ``nominal`` and ``split_up`` (turns 0.99), every action's ensemble spread ``spread``
    (2, 8, 3, 12), a topology change costing 0.5."""
    from qz_drake.capability.model import CapabilityMap

    nx, ny = 12, 3
    shape = (2, 8, ny, nx)
    forward = np.empty(shape)
    forward[0], forward[1] = nominal, split_up
    turn = np.full(shape, 0.99)
    capability_map = CapabilityMap(xs=0.5 + np.arange(nx), ys=0.5 + np.arange(ny),
                                   topologies=("nominal", "split_up"), forward=forward, turn_left=turn,
                                   turn_right=turn.copy(), forward_spread=spread, turn_left_spread=spread,
                                   turn_right_spread=spread)
    return plan_on_map(capability_map, (0.5, 1.5), 0, (11.5, 1.5),
                       config=CapabilityMdpConfig(topology_change_cost=0.5, **config))


def test_an_ensembles_disagreement_stops_a_switch_that_gains_less():
    """Two topologies on open ground: split_up's networks say 0.97 per move against nominal's
    0.93, but its ensemble's members disagree by 0.08. With the members' mean alone the robot
    changes to split_up; planned pessimistically (p - spread) it stays nominal, and where the
    members agree (spread 0.01) the gain exceeds the doubt and it changes again."""
    spread = np.zeros((2, 8, 3, 12))
    spread[1] = 0.08

    def route(spread, **config):
        return _open_ground_route(0.93, 0.97, spread, **config)

    assert route(spread, pessimism=0.0).topology_changes == 1
    doubtful = route(spread)
    assert doubtful.reaches_goal and doubtful.topology_changes == 0
    assert route(np.where(spread > 0, 0.01, 0.0)).topology_changes == 1
    with pytest.raises(QzError, match=r"capability_mdp.pessimism"):
        route(spread, pessimism=-1.0)


def test_topology_doubt_weighs_a_switch_by_the_doubt_about_the_difference():
    """split_up 0.955 per move against nominal's 0.94, nominal's members spread 0.02 and
    split_up's 0.003: doubting each topology by its own spread makes split_up look 0.032 better
    and the robot changes; with ``topology_doubt`` the 0.015 gain is within the doubt about the
    difference (sqrt(0.02^2 + 0.003^2) = 0.020) and it stays nominal. A gain of 0.05 exceeds it
    and it changes; a topology that is worse is not made better by its smaller spread."""
    spread = np.zeros((2, 8, 3, 12))
    spread[0], spread[1] = 0.02, 0.003

    def route(other, **config):
        return _open_ground_route(0.94, other, spread, **config)

    assert route(0.955, topology_doubt=False).topology_changes == 1
    stays = route(0.955)  # on by default
    assert stays.reaches_goal and stays.topology_changes == 0
    assert route(0.99, topology_doubt=True).topology_changes == 1
    assert route(0.93, topology_doubt=True).topology_changes == 0
    with pytest.raises(QzError, match=r"capability_mdp.topology_doubt"):
        route(0.955, topology_doubt="yes")


def test_the_plan_keeps_the_feet_on_the_map():
    """A flat 10 m x 5 m world, start and goal in the row of cells 0.5 m from its lower edge:
    Qingzhui's feet reach 0.83 m from its centre, so that row would walk them off the world (two
    validation walks did). The plan goes along the row inside, back to the goal's cell at the
    end; every cell it passes but the goal's is MAP_EDGE_REACH inside the edges."""
    from qz_drake.planning.capability_mdp import MAP_EDGE_REACH, cells_on_map, plan
    from qz_drake.terrain import HeightMap

    heightmap = HeightMap(np.zeros((100, 200)), 0.05, origin=(0.0, 0.0))  # x 0-9.95, y 0-4.95
    result = plan(FlatStub(), heightmap, (1.5, 0.5), 0, (8.5, 0.5), config=CapabilityMdpConfig(topologies=["nominal"]))
    assert result.reaches_goal
    inside = cells_on_map(heightmap, result.mdp.xs, result.mdp.ys)
    visited = result.cells[1:-1]
    assert len(visited) and all(y - MAP_EDGE_REACH >= 0.0 for _, y in visited)
    assert not inside[0].any() and inside[1, 1:-1].all()


@pytest.mark.parametrize("start, goal, named", [((0.0, 0.0), (4.0, 0.0), "goal_xy = (4.0, 0.0)"),
                                                ((-9.0, 0.0), (1.0, 0.0), "start_xy = (-9.0, 0.0)"),
                                                ((0.0, 0.0), (float("nan"), 0.0), "goal_xy = (nan, 0.0)")])
def test_a_start_or_goal_off_the_map_is_named_before_any_planning(start, goal, named):
    heightmap = HeightMap(np.zeros((40, 100)), 0.05, (-1.0, -1.0))  # x in [-1, 3.95]
    with pytest.raises(QzError, match=re.escape(named) + ".*off the map"):
        plan(None, heightmap, start, 0, goal)  # refused before the model is asked anything


def _flat_map_with_box(x_range, y_range):
    """14 m x 12 m of flat ground at 5 cm cells with one 0.15 m box over x_range x y_range."""
    res = 0.05
    X, Y = np.meshgrid(0.025 + res * np.arange(280), 0.025 + res * np.arange(240))
    inside = (X > x_range[0]) & (X < x_range[1]) & (Y > y_range[0]) & (Y < y_range[1])
    return HeightMap(np.where(inside, 0.15, 0.0), res, (0.025, 0.025))


def test_a_move_near_an_edge_costs_what_edge_cost_says_and_routes_keep_their_distance():
    """Issue 54 (session 49): the BLC refuses at edges; CapPlanner may charge a move for passing
    near one. A flat 14 m x 12 m map with a low box (0.15 m, which the stub model walks over
    and past alike) just beside the straight line from start to goal."""
    from qz_drake.planning.capability_mdp import HEADING_STEPS, edge_clearances

    res = 0.05
    hm = _flat_map_with_box((6.2, 6.8), (5.8, 7.0))
    config = CapabilityMdpConfig(topologies=["nominal"], edge_cost=5.0)
    cm = predict_map(StubModel(default=1.0), hm, ["nominal"], anchor=START)
    clearance = edge_clearances(hm, cm.xs, cm.ys, config)
    assert clearance.shape == (len(HEADING_STEPS) + 1, len(cm.ys), len(cm.xs))
    ix, iy = int(np.argmin(np.abs(cm.xs - 5.5))), int(np.argmin(np.abs(cm.ys - 5.5)))
    # From (5.5, 5.5) east to (6.5, 5.5) the path runs 0.3 m below the box: within the reach.
    assert clearance[0, iy, ix] == pytest.approx(0.3 - res / 2, abs=res)
    far = int(np.argmin(np.abs(cm.ys - 1.5)))
    assert clearance[0, far, ix] == config.edge_reach and clearance[-1, far, ix] == config.edge_reach
    # No cost: the rewards of before, and the clearance not needed.
    plain = build_capability_mdp(cm, GOAL, dataclasses.replace(config, edge_cost=0.0))
    costly = build_capability_mdp(cm, GOAL, config, edge_clearance=clearance)
    # A forward move in heading 0 (action 0) from (5.5, 5.5): charged (1 - 0.275 / 0.5) x 5.
    state = costly.state(ix, iy, 0, "nominal")
    assert plain.R[state, 0] - costly.R[state, 0] == pytest.approx(5.0 * (1 - clearance[0, iy, ix] / 0.5))
    assert costly.R[costly.state(ix, far, 0, "nominal"), 0] == plain.R[plain.state(ix, far, 0, "nominal"), 0]
    with pytest.raises(QzError, match="edge_clearance"):
        build_capability_mdp(cm, GOAL, config)
    with pytest.raises(QzError, match="edge_reach"):
        CapabilityMdpConfig(edge_reach=0.0).check()
    # The route: straight along y = 5.5 m without the cost; with a cost worth the detour's turns
    # and its longer moves' risk, a cell farther from the box.
    straight = plan(StubModel(default=1.0), hm, START, 0, GOAL, config=dataclasses.replace(config, edge_cost=0.0))
    kept = plan(StubModel(default=1.0), hm, START, 0, GOAL, config=dataclasses.replace(config, edge_cost=20.0))
    assert straight.reaches_goal and kept.reaches_goal
    assert np.allclose(straight.cells[:, 1], 5.5)
    assert not np.any(np.isclose(kept.cells[:, 1], 5.5) & np.isclose(kept.cells[:, 0], 6.5))


def test_a_turn_beside_an_edge_fails_as_often_as_turn_edge_risk_says_and_routes_turn_away_from_it():
    """Issue 54 (session 53): the walks' turns in place beside a box failed 43 % of the time,
    the model said 0.2 %. A flat map with a low box (0.15 m) 0.1 m south-west of the start
    cell's centre; the goal 5 m north of the start, the robot facing east."""
    from qz_drake.planning.capability_mdp import edge_clearances, restore_actions, set_stance

    hm = _flat_map_with_box((0.9, 1.4), (4.7, 5.4))
    goal = (1.5, 10.5)
    config = CapabilityMdpConfig(topologies=["nominal"], turn_edge_risk=0.6)
    cm = predict_map(StubModel(default=1.0), hm, ["nominal"], anchor=START)
    clearance = edge_clearances(hm, cm.xs, cm.ys, config)
    ix, iy = int(np.argmin(np.abs(cm.xs - 1.5))), int(np.argmin(np.abs(cm.ys - 5.5)))
    plain = build_capability_mdp(cm, goal, dataclasses.replace(config, turn_edge_risk=0.0))
    risky = build_capability_mdp(cm, goal, config, edge_clearance=clearance)
    start = risky.state(ix, iy, 0, "nominal")
    kept = 1.0 - 0.6 * (1.0 - clearance[-1, iy, ix] / config.turn_edge_reach)
    assert 0.0 < clearance[-1, iy, ix] < 0.2
    # The turns from the start lose the risk's share (to a fall); its forward move loses nothing.
    assert risky.success[1, start] == pytest.approx(plain.success[1, start] * kept)
    assert risky.success[2, start] == pytest.approx(plain.success[2, start] * kept)
    assert risky.success[0, start] == plain.success[0, start]
    far = risky.state(ix, int(np.argmin(np.abs(cm.ys - 8.5))), 0, "nominal")
    assert risky.success[1, far] == plain.success[1, far]
    # From the stance the robot stands in (set_stance), the same share goes.
    saved = set_stance(risky, start, np.array([[1.0, 1.0, 0.0]] * 3))
    assert risky.success[1, start] == pytest.approx(kept) and risky.success[0, start] == 1.0
    restore_actions(risky, saved)
    with pytest.raises(QzError, match="edge_clearance"):
        build_capability_mdp(cm, goal, config)
    with pytest.raises(QzError, match="turn_edge_risk"):
        CapabilityMdpConfig(turn_edge_risk=1.5).check()
    # The route: without the risk it turns north where it stands; with it, it steps away first.
    turned_here = plan(StubModel(default=1.0), hm, START, 0, goal, config=dataclasses.replace(config, turn_edge_risk=0))
    away = plan(StubModel(default=1.0), hm, START, 0, goal, config=config)
    assert turned_here.reaches_goal and away.reaches_goal
    assert turned_here.steps[0].motion != "forward"
    assert away.steps[0].motion == "forward"
    assert all(s.motion == "forward" for s in away.steps if np.hypot(s.x - 1.5, s.y - 5.5) < 0.5)


def test_a_plan_expects_its_walk_by_the_models_mean_with_refusals_gone_round():
    """What a plan predicts of its walk (issue 54's route calibration): the plan weighs each move
    as p - spread with the tuned share of refusals counted as failures; its expectation of the
    walk is the model's mean, a refusal leaving the robot standing (the TLC goes round it)."""
    from qz_drake.capability.model import CapabilityMap

    nx, ny = 12, 3
    shape = (1, 8, ny, nx)
    walked, planned = np.full(shape, 0.9), np.full(shape, 0.95)  # 0.05 refused, 0.05 failed walking
    turn, spread = np.full(shape, 0.99), np.full(shape, 0.04)
    capability_map = CapabilityMap(xs=0.5 + np.arange(nx), ys=0.5 + np.arange(ny), topologies=("nominal",),
                                   forward=walked, turn_left=turn, turn_right=turn.copy(), forward_plan=planned,
                                   turn_left_plan=np.ones(shape), turn_right_plan=np.ones(shape),
                                   forward_spread=spread, turn_left_spread=np.zeros(shape),
                                   turn_right_spread=np.zeros(shape))
    result = plan_on_map(capability_map, (0.5, 1.5), 0, (11.5, 1.5),
                         config=CapabilityMdpConfig(plan_failure_risk=1.0))
    moves = [s for s in result.steps if s.motion == "forward"]
    assert result.reaches_goal and len(moves) == 11 and len(result.steps) == 11
    # As planned: 0.86 a move, every failure a fall. Expected: 0.95 a move.
    assert result.fall_free_probability == pytest.approx(0.86 ** 11)
    assert result.expected_fall_free() == pytest.approx(0.95 ** 11)
    bare = dataclasses.replace(result, capability_map=None)
    with pytest.raises(QzError, match="capability_map"):
        bare.expected_fall_free()


def test_an_arrivals_charge_routes_round_the_cell_and_outlasts_the_robots_stance():
    """charge_arrivals (CapabilityVIPlanner's revisit_cost): every forward move into a cell costs
    more, so the route goes round it; set_stance, which recomputes the start's moves from the
    robot's stance, keeps the charge, and restore_actions gives it back as it was."""
    from qz_drake.planning.capability_mdp import (charge_arrivals, most_likely_path, restore_actions, set_stance,
                                                  solve_capability_mdp)

    result = _open_ground_route(0.97, 0.97, np.zeros((2, 8, 3, 12)), topologies=["nominal"])
    assert np.allclose(result.cells[:, 1], 1.5)  # straight along the middle row
    mdp = result.mdp
    before = mdp.R.copy()
    # Cell (5, 1): from each of its 8 neighbours one heading leads into it, in either of the map's
    # two topologies from a state of either: 8 x 2 x 2 moves.
    assert charge_arrivals(mdp, 5, 1, 30.0) == 32
    into = mdp.state(4, 1, 0, "nominal")
    assert mdp.R[into, 0] == pytest.approx(before[into, 0] - 30.0 * mdp.success[0, into])
    saved = set_stance(mdp, into, np.array([[0.97, 1.0, 0.0], [0.99, 1.0, 0.0], [0.99, 1.0, 0.0]]))
    assert mdp.R[into, 0] == pytest.approx(before[into, 0] - 30.0 * 0.97)
    restore_actions(mdp, saved)
    solution = solve_capability_mdp(mdp)
    steps, reaches, _ = most_likely_path(mdp, solution, mdp.state(0, 1, 0, "nominal"))
    assert reaches and not any(np.isclose(s.x, 5.5) and np.isclose(s.y, 1.5) for s in steps)
    with pytest.raises(QzError, match="cell"):
        charge_arrivals(mdp, 12, 1, 1.0)
