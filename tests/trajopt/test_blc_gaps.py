"""Gaps (issue 11): Qingzhui crosses the bench suite's 0.3 m gap with the stance-window foothold
guess and free phase durations, and the saved plan passes the independent checks at every 100 Hz sample: stance feet on
the ground beside the gap, never over it; swing feet above the terrain; forces and residuals as
on any other terrain."""

import numpy as np
import pytest

from qz_drake.config import TerrainConfig
from qz_drake.station import make_heightmap
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.solver import BlcTask, solve_blc
from tests.trajopt.npz_checks import assert_plan_holds, bilinear

GAP_START, GAP_WIDTH = 0.9, 0.3  # [m]


@pytest.fixture(scope="module")
def gap_map():
    return make_heightmap(TerrainConfig(kind="gap", params=dict(width=GAP_WIDTH, depth=0.5,
                                                                start_x=GAP_START)))


def test_qingzhui_crosses_the_gap(gap_map, tmp_path):
    # With fixed timing the same guess converges too, but its angular residual between samples
    # came out at 0.055 body weights (limit 0.05); free durations give the swings over the gap
    # more time (BENCHMARKS "blc").
    params = BlcParameters(foothold_guess="stance", optimize_phase_durations=True,
                           time_limit=60.0)
    solution = solve_blc(BlcTask(target=(1.5, 0.0, 0.0), duration=3.0), terrain=gap_map,
                         params=params)
    assert solution.success, solution.reason
    data = dict(np.load(solution.save_npz(tmp_path / "gap.npz")))
    assert_plan_holds(data, "qz gap")
    feet, contact = data["foot_pos"], data["contact"]
    h, *_ = bilinear(data, feet[..., 0], feet[..., 1])
    # Every stance foot stands on the ground, none over the gap (its floor is 0.5 m down)...
    assert h[contact].min() > -0.01
    sole_x = feet[..., 0][contact]
    assert not np.any((sole_x > GAP_START + 0.02) & (sole_x < GAP_START + GAP_WIDTH - 0.02))
    # ... and every foot did cross it: it started before the gap and ended beyond it, or
    # (the hind feet of a 1.5 m walk) stayed before it.
    start, end = feet[0, :, 0], feet[-1, :, 0]
    crossed = (start < GAP_START) & (end > GAP_START + GAP_WIDTH)
    assert crossed.sum() >= 3, (start, end)


def test_stance_foothold_guess_looks_past_a_gap_that_fills_the_mid_stance_box(gap_map):
    """RF's box at mid-stance (body 0.6 -> 0.8 m) lies over the gap (its 0.7 x box: x = 0.965 to
    1.175);
    the mid-stance guess puts the foot in the gap, the stance guess on the ground beyond it."""
    from qz_drake.trajopt.initial_guess import choose_foothold, choose_stance_foothold
    from qz_drake.trajopt.robot_model import qingzhui
    from qz_drake.trajopt.terrain import as_terrain

    robot, terrain = qingzhui("nominal"), as_terrain(gap_map)
    inside = choose_foothold(robot, terrain, 1, np.array([0.7, 0.0]), 0.0, 0.0)
    assert inside[2] < -0.4  # the gap's floor (centre 0.5 m down, plus the foot radius)
    chosen = choose_stance_foothold(robot, terrain, 1, np.array([[0.6, 0.0], [0.8, 0.0]]),
                                    np.zeros(2), 0.0)
    assert chosen[0] > GAP_START + GAP_WIDTH + robot.foot_radius
    assert chosen[2] == pytest.approx(robot.foot_radius, abs=1e-6)


def test_the_default_guess_looks_past_the_gap_on_a_move_and_keeps_mid_stance_on_a_turn(gap_map):
    """foothold_guess "auto" (the default): the stance window for a task that travels, the
    mid-stance box for a turn in place (measured on the capability trials: the window helped
    moves and not turns)."""
    from qz_drake.trajopt.formulation import BlcFormulation
    from qz_drake.trajopt.gait import make_gait
    from qz_drake.trajopt.initial_guess import foothold_guess, straight_line_guess
    from qz_drake.trajopt.robot_model import qingzhui
    from qz_drake.trajopt.solver import standing_start
    from qz_drake.trajopt.terrain import as_terrain

    robot, terrain = qingzhui("nominal"), as_terrain(gap_map)
    assert BlcParameters().foothold_guess == "auto"
    start, rpy, feet = standing_start(robot, terrain)

    def guess(target, choice):
        params = BlcParameters(foothold_guess=choice)
        schedule = make_gait("tripod", robot.num_legs, 3.0, stand_duration=params.stand_duration)
        f = BlcFormulation(robot, terrain, params, schedule, start_position=start,
                           start_rpy=rpy, start_feet=feet, target=target)
        return foothold_guess(f), straight_line_guess(f)

    move, turn = (1.5, 0.0, 0.0), (0.0, 0.0, 0.8)
    (used, x_auto), (_, x_stance), (_, x_mid) = (guess(move, c) for c in ("auto", "stance", "mid"))
    assert used == "stance"
    np.testing.assert_array_equal(x_auto, x_stance)
    assert np.abs(x_auto - x_mid).max() > 0.05
    (used, x_auto), (_, x_mid) = (guess(turn, c) for c in ("auto", "mid"))
    assert used == "mid"
    np.testing.assert_array_equal(x_auto, x_mid)
    with pytest.raises(Exception, match="blc.foothold_guess"):
        BlcParameters(foothold_guess="window")


def test_the_stance_guess_does_not_stand_a_foot_on_top_of_a_wall():
    """The window's upper quartile of heights is the reference ground over a hole; beside a
    1 m wall that fills most of the window it must not become the wall's top, out of the
    leg's reach (the walking test into a wall then failed its first mission)."""
    from qz_drake.trajopt.initial_guess import choose_stance_foothold
    from qz_drake.trajopt.robot_model import qingzhui
    from qz_drake.trajopt.terrain import as_terrain

    robot = qingzhui("nominal")
    wall = as_terrain(make_heightmap(TerrainConfig(kind="step", params=dict(height=1.0,
                                                                              start_x=1.0))))
    # MF (leg 0, nominal x = 0.75 m, box +-0.15 m) with the body from x = 0.2 to 0.4: its
    # window spans x = 0.8 to 1.3 m, 60 % of it on the wall.
    chosen = choose_stance_foothold(robot, wall, 0, np.array([[0.2, 0.0], [0.4, 0.0]]),
                                    np.zeros(2), 0.0)
    assert chosen[0] < 1.0 - robot.foot_radius
    assert chosen[2] == pytest.approx(robot.foot_radius, abs=1e-6)


def test_every_swing_lifts_above_both_footholds_where_the_ground_is_not_level(gap_map):
    """Over a gap the apex's terrain row is met by a foot that never lifts (the floor under the
    apex is 0.5 m down), so the swing/lift rows hold each apex swing_lift_height above both of
    its footholds; on level ground they are not added (the apex row already implies them)."""
    from qz_drake.trajopt.formulation import BlcFormulation
    from qz_drake.trajopt.gait import make_gait
    from qz_drake.trajopt.initial_guess import straight_line_guess
    from qz_drake.trajopt.robot_model import qingzhui
    from qz_drake.trajopt.solver import standing_start
    from qz_drake.trajopt.terrain import as_terrain

    robot = qingzhui("nominal")

    def formulation(terrain, lift=0.06):
        params = BlcParameters(swing_lift_height=lift)
        schedule = make_gait("tripod", robot.num_legs, 3.0, stand_duration=params.stand_duration)
        start, rpy, feet = standing_start(robot, terrain)
        return BlcFormulation(robot, terrain, params, schedule, start_position=start,
                              start_rpy=rpy, start_feet=feet, target=(1.5, 0.0, 0.0))

    f = formulation(as_terrain(gap_map))
    [lift] = [t for t in f.linear if t.name == "swing/lift"]
    v = f.variables
    assert lift.num_constraints == 2 * sum(len(a) for a in v.apex_heights)
    x = straight_line_guess(f)
    # The guess lifts each apex 1.5 apex heights above the higher foothold: the rows hold...
    assert lift.violation(x).max() == 0.0
    # ... and an apex 2 cm over the foothold it leaves violates its row by 4 cm.
    leg, s = 1, 1
    x[v.apex_heights[leg][s]] = x[v.footholds[leg][s, 2]] + 0.02
    assert lift.violation(x).max() == pytest.approx(0.04, abs=1e-9)
    assert all(t.name != "swing/lift" for t in formulation(as_terrain(None)).linear)
    assert all(t.name != "swing/lift" for t in formulation(as_terrain(gap_map), lift=None).linear)
    with pytest.raises(Exception, match="blc.swing_lift_height"):
        BlcParameters(swing_lift_height=-0.01)


def test_a_foot_crossing_a_trench_lifts_off_its_edge_first():
    """The mission of the demo's seed-2 crossing (long_range) that starts at t = 35.3 s, from the
    state measured there: LF crosses a 0.4 m deep trench beside the body. With only the apex's
    terrain row its swing lifted 2.5 mm off the edge it left and slid 5.9 cm along it in Drake
    (a failed walk); with the swing/lift rows each LF swing rises at least 6 cm above both of
    its footholds."""
    from qz_drake.demo import demo_scenario

    scenario = demo_scenario(seed=2)
    world = make_heightmap(scenario.terrain, scenario.random_seed)
    feet = np.array([[4.521, 7.5197, 0.0276], [4.636, 6.8392, 0.0274], [4.1123, 6.3175, 0.0276],
                     [3.4308, 6.4308, 0.0277], [3.3172, 7.1127, 0.0276], [3.8393, 7.6343, 0.0274]])
    task = BlcTask(target=(5.0, 8.0, 0.7854), start_position=(3.9813, 6.9818, 0.5147),
                   start_rpy=(-0.0004, 0.0007, 0.7853), start_feet=feet, duration=5.6)
    params = BlcParameters(max_iterations=30, time_limit=120.0)  # a CapPlanner walk's budget
    solution = solve_blc(task, terrain=world, params=params)
    assert solution.success, solution.reason
    lf = solution.foot_positions[5]
    lifts = []
    for t0, t1 in solution.contact_schedule.swing_intervals(5):
        t = np.linspace(t0, t1, 61)
        z = np.array([lf.value(s).ravel()[2] for s in t])
        lifts.append(z.max() - max(z[0], z[-1]))
    assert min(lifts) >= 0.06 - 1e-4, lifts
    # LF starts before the trench (y 7.82-8.12 m here) and ends beyond it: one swing crossed it.
    assert lf.value(0.0).ravel()[1] < 7.82 and lf.value(solution.duration).ravel()[1] > 8.12
