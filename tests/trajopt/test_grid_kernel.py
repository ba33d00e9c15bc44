"""The BLC's hot paths compiled or reused without changing a number (issue 53, "the Python
around Ipopt"): the grid terrain's heights and derivatives and the verdict's raw cells by numba
loops equal to the numpy forms to the bit; Ipopt's Jacobian after its constraints at the same
point taken from the same evaluation; a program's Jacobian structure kept for the next program
of that structure."""

import numpy as np
import pytest

from qz_drake.errors import QzError
from qz_drake.terrain import make_terrain
from qz_drake.trajopt import ipopt_mumps
from qz_drake.trajopt.formulation import BlcFormulation
from qz_drake.trajopt.gait import make_gait
from qz_drake.trajopt.initial_guess import straight_line_guess
from qz_drake.trajopt.ipopt_mumps import ProgramNlp
from qz_drake.trajopt.leg_clearance import RawCells, raw_ground, sphere_clearance
from qz_drake.trajopt.parameters import BlcParameters
from qz_drake.trajopt.robot_model import qingzhui
from qz_drake.trajopt.solver import standing_start
from qz_drake.trajopt.terrain import GridTerrain, as_terrain


def _bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def _points(terrain: GridTerrain, count: int, seed: int):
    """Points over the map and half a metre past its border, every node of a few rows, and
    infinities (the border's plateau)."""
    rng = np.random.default_rng(seed)
    H, W = terrain.heights.shape
    res, (x0, y0) = terrain.resolution, terrain.origin
    x = rng.uniform(x0 - 0.5, x0 + (W - 1) * res + 0.5, count)
    y = rng.uniform(y0 - 0.5, y0 + (H - 1) * res + 0.5, count)
    nodes_x = x0 + res * np.arange(W)
    nodes_y = np.full(W, y0 + res * (H // 2))
    return (np.concatenate([x, nodes_x, [np.inf, -np.inf, x0]]),
            np.concatenate([y, nodes_y, [y0, y0, np.inf]]))


@pytest.mark.parametrize("kind", ["stairs", "obstacles"])
def test_grid_heights_and_derivatives_are_the_numpy_forms_to_the_bit(kind):
    terrain = GridTerrain(make_terrain(kind, seed=7))
    x, y = _points(terrain, 20000, seed=1)
    for compiled, reference in zip(terrain.height_derivatives(x, y), terrain.height_derivatives_numpy(x, y)):
        np.testing.assert_array_equal(_bits(compiled), _bits(reference))
    np.testing.assert_array_equal(_bits(terrain.height(x, y)), _bits(terrain.height_numpy(x, y)))
    # Shapes broadcast as numpy's do; a point gives a numpy scalar.
    grid = terrain.height(x[:12].reshape(3, 4), y[:1])
    assert grid.shape == (3, 4)
    np.testing.assert_array_equal(_bits(grid), _bits(terrain.height_numpy(x[:12].reshape(3, 4), y[:1])))
    one = terrain.height(float(x[0]), float(y[0]))
    assert isinstance(one, np.float64) and one == terrain.height_numpy(float(x[0]), float(y[0]))


def test_a_nan_point_is_refused_by_name():
    terrain = GridTerrain(make_terrain("stairs", seed=7))
    with pytest.raises(QzError, match="terrain query.*NaN"):
        terrain.height(np.array([0.0, np.nan]), np.array([0.0, 0.0]))
    with pytest.raises(QzError, match="terrain query.*NaN"):
        raw_ground(terrain).highest(np.array([np.nan]), np.array([0.0]), np.zeros(1), np.zeros(1))


def test_the_highest_raw_cell_under_a_sphere_is_the_numpy_forms():
    terrain = GridTerrain(make_terrain("obstacles", seed=3))
    ground = raw_ground(terrain)
    assert isinstance(ground, RawCells)
    x, y = _points(terrain, 6000, seed=2)
    z = np.random.default_rng(3).uniform(-0.5, 0.5, len(x))
    centres = np.column_stack([x, y, z])[:6000].reshape(60, 100, 3)
    compiled = sphere_clearance(centres, 0.03, ground)
    numpy_form = sphere_clearance(centres, 0.03, ground.__call__)  # a plain function: numpy
    np.testing.assert_array_equal(_bits(compiled), _bits(numpy_form))


def _program(distance: float = 1.0, terrain=None):
    robot, terrain = qingzhui(), as_terrain(terrain)
    params = BlcParameters()
    schedule = make_gait(robot.gaits[0], robot.num_legs, 2.0, stand_duration=params.stand_duration)
    start, rpy, feet = standing_start(robot, terrain)
    f = BlcFormulation(robot, terrain, params, schedule, start_position=start, start_rpy=rpy,
                       start_feet=feet, target=(distance, 0.0, 0.0))
    program = f.build_program(drake_ipopt=False)
    return f, ProgramNlp(program.prog, program.vectorised)


def test_the_jacobian_after_the_constraints_at_a_point_is_the_fresh_one_and_no_other_points():
    f, nlp = _program()
    rng = np.random.default_rng(0)
    x1 = straight_line_guess(f) + 1e-3 * rng.standard_normal(f.variables.num_vars)
    x2 = x1 + 1e-3 * rng.standard_normal(f.variables.num_vars)
    # References from fresh programs, the Jacobian asked for first, so that nothing is kept.
    reference = {k: (_program()[1].constraints(x), _program()[1].jacobian(x)) for k, x in (("1", x1), ("2", x2))}
    calls = {"both": 0}
    for block in nlp.blocks:
        if block.both is not None:
            block.both = (lambda both: lambda x: (calls.__setitem__("both", calls["both"] + 1), both(x))[1])(block.both)
    vectorised = sum(block.both is not None for block in nlp.blocks)

    # Ipopt's usual order: the constraints, then the Jacobian at the same point.
    np.testing.assert_array_equal(nlp.constraints(x1), reference["1"][0])
    np.testing.assert_array_equal(nlp.jacobian(x1), reference["1"][1])
    assert calls["both"] == vectorised  # one evaluation for both
    # The Jacobian at another point than the one kept is that point's.
    np.testing.assert_array_equal(nlp.constraints(x2), reference["2"][0])
    np.testing.assert_array_equal(nlp.jacobian(x1), reference["1"][1])
    # A line search: the constraints at x2, then at x1 without a Jacobian between (x1's alone,
    # nothing kept); then the Jacobian at x1.
    nlp.constraints(x2)
    before = calls["both"]
    np.testing.assert_array_equal(nlp.constraints(x1), reference["1"][0])
    assert calls["both"] == before
    np.testing.assert_array_equal(nlp.jacobian(x1), reference["1"][1])
    np.testing.assert_array_equal(nlp.constraints(x2), reference["2"][0])
    np.testing.assert_array_equal(nlp.jacobian(x2), reference["2"][1])


def test_programs_of_one_structure_share_it_and_others_get_their_own():
    _, a = _program(1.0)
    _, b = _program(0.8)  # other bounds, the same rows and columns
    _, c = _program(1.0, make_terrain("stairs", seed=7))  # leg and support rows: another structure
    assert a._rows is b._rows and a._inverse is b._inverse
    assert c._rows is not a._rows and len(c._inverse) != len(a._inverse)
    assert not a._rows.flags.writeable
    # What is shared is what np.unique gives.
    positions = np.concatenate([blk.rows + o for blk, o in zip(
        a.blocks, np.cumsum([0] + [len(blk.lower) for blk in a.blocks]))]) * a.num_vars + \
        np.concatenate([blk.cols for blk in a.blocks])
    keys, inverse = np.unique(positions, return_inverse=True)
    np.testing.assert_array_equal(a._rows, keys // a.num_vars)
    np.testing.assert_array_equal(a._cols, keys % a.num_vars)
    np.testing.assert_array_equal(a._inverse, inverse)
    assert len(ipopt_mumps._STRUCTURES) <= ipopt_mumps._STRUCTURES_KEPT
