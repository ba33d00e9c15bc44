"""Support under stance feet (trajopt/support.py): the field, its constraint's exact Jacobian,
a solve that keeps its footholds off a pit's rim, and the dense verdict failing a plan that
stands a foot on an edge."""

import numpy as np
import pytest

from qz_drake.terrain.heightmap import HeightMap
from qz_drake.trajopt import terrain as tt
from qz_drake.trajopt.initial_guess import straight_line_guess
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import qingzhui
from qz_drake.trajopt.solver import BlcTask, solve_blc
from qz_drake.trajopt.support import SupportConstraint, field_from_grid, support_field
from qz_drake.trajopt.verdict import dense_check
from tests.trajopt.test_blc_constraints import _formulation

RES = 0.05


def _pit_map(x0=0.5, x1=0.9, depth=0.2, size=4.0):
    """Flat ground with a pit x0 <= x < x1 across the whole map (edges on cell boundaries)."""
    n = int(round(size / RES))
    origin = (-size / 2 + RES / 2, -size / 2 + RES / 2)
    xs = origin[0] + RES * np.arange(n)
    heights = np.zeros((n, n))
    heights[:, (xs >= x0) & (xs < x1)] = -depth
    return HeightMap(heights, RES, origin)


def test_the_field_marks_both_sides_of_an_edge_and_points_out_of_it():
    heightmap = _pit_map()
    field = field_from_grid(heightmap.heights, RES, heightmap.origin, radius=0.08, drop=0.05)
    y = 0.0
    # Rim cells (within 0.08 m of the pit's edge at x = 0.5) and the pit's floor next to its
    # wall are unsupported; 0.2 m away on either side is supported.
    assert field.unsupported_at(0.475, y) and field.unsupported_at(0.525, y)
    assert not field.unsupported_at(0.3, y) and not field.unsupported_at(0.7, y)
    assert field.relief_at(0.475, y) == pytest.approx(0.2)
    # Signed distance: positive on the ground well away from the edge, negative on the rim,
    # growing away from the edge.
    assert field.margin(0.2, y) > 0.1 and field.margin(0.475, y) < 0.0
    assert field.margin(0.35, y) > field.margin(0.40, y)
    # The nearest supported point of a rim point is off the rim, on the near side.
    (moved,) = field.nearest_supported([0.475], [y])
    assert moved[0] < 0.45 and not field.unsupported_at(*moved)
    # Gentle ground (a 20 degree slope) is supported everywhere.
    xs = np.arange(80) * RES
    slope = np.tile(np.tan(np.radians(20)) * xs, (20, 1))
    assert not field_from_grid(slope, RES, (0, 0), 0.08, 0.05).unsupported.any()


def test_support_constraint_jacobian_matches_finite_differences():
    """At footholds on the rim (where the field is not clipped), the analytic Jacobian of the
    support rows equals central differences over the whole decision vector."""
    f = _formulation(tt.as_terrain(_pit_map(x0=0.3, x1=0.7)), 1.2, (0.4, 0.0, 0.0))
    [c] = [c for c in f.nonlinear if isinstance(c, SupportConstraint)]
    x = straight_line_guess(f)
    v = f.variables
    rng = np.random.default_rng(1)
    for leg in range(v.num_legs):  # every free foothold within 6 cm of an edge
        for s in range(1, len(v.footholds[leg])):
            idx = v.footholds[leg][s]
            x[idx[0]] = rng.choice([0.3, 0.7]) + rng.uniform(-0.06, 0.06)
    values = c.evaluate(x)
    assert np.all(np.abs(values) < 0.25)  # inside the unclipped band
    J = c.jacobian(x, v.num_vars).toarray()
    fd = np.zeros_like(J)
    for k in np.unique(c.cols):
        e = np.zeros(v.num_vars)
        e[k] = 1e-6
        fd[:, k] = (c.evaluate(x + e) - c.evaluate(x - e)) / 2e-6
    assert np.abs(fd).max() > 0.5  # the field does vary there
    np.testing.assert_allclose(J, fd, atol=1e-5)
    # Where every foothold in reach is supported the program has no support rows at all.
    flat = _formulation(tt.flat(), 1.2, (0.4, 0.0, 0.0))
    assert flat.support is None and not any(isinstance(c, SupportConstraint) for c in flat.nonlinear)


def test_a_walk_beside_a_pit_keeps_every_stance_foot_off_its_rim():
    """A 1 m walk along a 0.2 m pit whose rim lies under the left feet's nominal footholds:
    the plan solves, every free stance foothold is on supported ground at the raw heightmap
    (no drop > 5 cm within 8 cm), and the dense verdict agrees."""
    n = int(round(4.0 / RES))
    origin = (-2.0 + RES / 2, -2.0 + RES / 2)
    ys = origin[1] + RES * np.arange(n)
    heights = np.zeros((n, n))
    heights[ys >= 0.55, :] = -0.2  # the pit's rim runs along y = 0.55, under two feet
    terrain = tt.as_terrain(HeightMap(heights, RES, origin))
    robot = qingzhui("nominal")
    assert np.any(np.abs(robot.nominal_footholds[:, 1] - 0.55) < 0.02), "the rim must be under nominal footholds"
    solution = solve_blc(BlcTask(target=(1.0, 0.0, 0.0), duration=4.0), robot, terrain,
                         BlcParameters(time_limit=60.0))
    assert solution.success, solution.reason
    field = support_field(terrain, robot.foot_radius + 0.05, 0.05)
    # The saved 100 Hz samples: every stance foot after its first stance (the start's footholds
    # are given, not planned).
    samples = solution.sample()
    schedule = solution.contact_schedule
    free = np.concatenate([samples["foot_pos"][samples["contact"][:, leg] & (samples["t"] > schedule.stance_intervals(leg)[0][1]), leg]
                           for leg in range(robot.num_legs)])
    assert len(free) > 100
    assert not field.unsupported_at(free[:, 0], free[:, 1]).any()
    assert solution.dense.min_support_margin >= -0.01


def test_the_dense_verdict_fails_a_foot_on_an_edge():
    """Without the support constraint the optimiser may stand a foot on a rim; the verdict
    (support still checked) names the foot and the drop."""
    f = _formulation(tt.as_terrain(_pit_map(x0=0.5, x1=0.9)), 2.0, (0.2, 0.0, 0.0))
    robot, feet = f.robot, f.start_feet
    x = straight_line_guess(f)
    assert dense_check(f, x).min_support_margin > 0.0
    idx = f.variables.footholds[0][1]  # leg 0's first free foothold onto the rim
    x[idx[0]], x[idx[1]] = 0.48, feet[0, 1]
    check = dense_check(f, x)
    assert check.min_support_margin < -0.01
    assert any(f"{robot.leg_names[0]} stance foot on unsupported ground" in r and "0.20 m" in r
               for r in check.failures), check.failures
