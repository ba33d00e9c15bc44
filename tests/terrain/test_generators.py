"""Generators make the terrain their names promise, seeded, with edges on cell boundaries."""

import math

import numpy as np
import pytest

from qz_drake.errors import TerrainError
from qz_drake.terrain import TERRAIN_KINDS, make_terrain, terrain_param_names


def _is_rectangle(mask: np.ndarray) -> bool:
    rows, cols = np.nonzero(mask)
    return bool(mask[rows.min():rows.max() + 1, cols.min():cols.max() + 1].all())


def _cell_edges_ok(hm) -> bool:
    """Cell boundaries lie on whole multiples of the resolution."""
    k = (hm.origin[0] - hm.resolution / 2) / hm.resolution, (hm.origin[1] - hm.resolution / 2) / hm.resolution
    return all(abs(v - round(v)) < 1e-9 for v in k)


@pytest.mark.parametrize("kind", sorted(TERRAIN_KINDS))
def test_every_generator_is_finite_seeded_and_starts_level(kind):
    a = make_terrain(kind, seed=1)
    b = make_terrain(kind, seed=1)
    np.testing.assert_array_equal(a.heights, b.heights)
    assert np.isfinite(a.heights).all()
    assert _cell_edges_ok(a)
    xmin, xmax, ymin, ymax = a.bounds
    assert xmin < -1.9 and xmax > 3.9 and ymin < -1.9 and ymax > 1.9  # reaches behind the start
    if kind != "rough":
        assert a.height(0.0, 0.0) == 0.0, kind


@pytest.mark.parametrize("kind", ["rough", "obstacles", "pits", "long_range"])
def test_random_generators_differ_across_seeds(kind):
    assert not np.array_equal(make_terrain(kind, seed=1).heights, make_terrain(kind, seed=2).heights)


def test_stairs_rise_count_and_edges():
    hm = make_terrain("stairs", rise=0.1, run=0.4, count=2, start_x=0.5)
    # Cell centres either side of the noses at x = 0.5 and 0.9.
    np.testing.assert_allclose(hm.height(np.array([0.475, 0.525, 0.875, 0.925, 3.9]), 0.0),
                               [0.0, 0.1, 0.1, 0.2, 0.2], atol=1e-12)
    levels = np.unique(hm.heights)
    np.testing.assert_allclose(levels, [0.0, 0.1, 0.2])
    # Piecewise constant: each level is one rectangle of cells spanning the map's width.
    for level in levels:
        mask = hm.heights == level
        assert _is_rectangle(mask) and mask.all(axis=0).sum() == mask.any(axis=0).sum()
    assert (hm.heights == 0.1).any(axis=0).sum() == 8  # 0.4 m run = 8 cells
    down = make_terrain("stairs", rise=-0.15, count=4, run=0.3, start_x=1.0)
    np.testing.assert_allclose(np.unique(down.heights), [-0.6, -0.45, -0.3, -0.15, 0.0], atol=1e-12)
    # An edge off the lattice snaps to the nearest cell boundary (0.51 -> 0.5).
    np.testing.assert_array_equal(make_terrain("stairs", start_x=0.51).heights, hm.heights)


def test_gap_depth_and_width():
    hm = make_terrain("gap", width=0.3, depth=0.5, start_x=0.6)
    assert hm.height(0.75, 0.0) == pytest.approx(-0.5)
    assert hm.height(0.575, 0.3) == 0.0 and hm.height(0.925, -0.3) == 0.0
    assert (hm.heights == -0.5).all(axis=0).sum() == 6  # 0.3 m / 0.05 m
    with pytest.raises(TerrainError, match=r"terrain\.width = -0\.2"):
        make_terrain("gap", width=-0.2)


def test_slope_angle_from_the_gradient():
    hm = make_terrain("slope", angle_deg=15.0, start_x=0.5)
    dx, dy = hm.gradient(np.array([1.0, 2.3, 3.5]), np.array([0.3, -1.0, 1.2]))
    np.testing.assert_allclose(np.degrees(np.arctan(dx)), 15.0)
    np.testing.assert_array_equal(dy, 0.0)
    assert hm.height(0.2, 0.0) == 0.0
    assert hm.height(2.5, 0.0) == pytest.approx(2.0 * math.tan(math.radians(15)))
    capped = make_terrain("slope", angle_deg=10.0, start_x=0.5, length=1.0)
    assert capped.height(3.0, 0.0) == pytest.approx(math.tan(math.radians(10)))


def test_step_block_and_step_that_stays():
    block = make_terrain("step", height=0.2, start_x=0.5, length=0.6)
    np.testing.assert_allclose(block.height(np.array([0.475, 0.525, 1.075, 1.125]), 0.0), [0, 0.2, 0.2, 0])
    stays = make_terrain("step", height=0.2, start_x=0.5)
    assert stays.height(3.9, 0.0) == pytest.approx(0.2)
    assert sorted(np.unique(stays.heights)) == pytest.approx([0.0, 0.2])


def _cells_near_start(hm, radius):
    """Mask of the cells whose square reaches within radius of (0, 0)."""
    x, y = np.meshgrid(hm.x_coords, hm.y_coords)
    half = hm.resolution / 2
    dx = np.maximum(np.abs(x) - half, 0.0)
    dy = np.maximum(np.abs(y) - half, 0.0)
    return np.hypot(dx, dy) < radius - 1e-9


def test_pits_are_seeded_squares_away_from_the_start():
    hm = make_terrain("pits", count=5, width=0.3, depth=0.2, seed=4)
    assert set(np.unique(hm.heights)) <= {0.0, -0.2}
    assert 0 < (hm.heights == -0.2).sum() <= 5 * 36
    assert np.all(hm.heights[_cells_near_start(hm, 0.8)] == 0.0)


def test_obstacles_keep_the_start_clear():
    for seed in range(5):
        hm = make_terrain("obstacles", count=20, min_height=0.1, max_height=0.3, seed=seed)
        assert np.all(hm.heights[_cells_near_start(hm, 0.8)] == 0.0)
        raised = hm.heights[hm.heights > 0]
        assert raised.size > 0 and raised.min() >= 0.1 and raised.max() <= 0.3
        assert len(np.unique(raised)) <= 20


def test_waves_and_rough():
    waves = make_terrain("waves", amplitude=0.05, wavelength=1.0)
    # The centres nearest the crest (0.25, 0) are a quarter cell off it: 0.05 sin(0.45 pi) cos(0.05 pi).
    crest = 0.05 * math.sin(0.45 * math.pi) * math.cos(0.05 * math.pi)
    assert waves.heights.max() == pytest.approx(crest)
    assert waves.height(0.25, 0.0) == pytest.approx(crest)
    assert waves.height(0.25, 0.5) == pytest.approx(-crest)  # the cosine's trough along y
    rough = make_terrain("rough", amplitude=0.04, correlation_length=0.2, seed=3)
    assert abs(rough.heights.mean()) < 1e-12
    assert np.abs(rough.heights).max() == pytest.approx(0.04)
    h = rough.heights - rough.heights.mean()
    lag1 = (h[:, 1:] * h[:, :-1]).mean() / (h * h).mean()
    assert lag1 > 0.9  # smooth over 0.2 m, with 0.05 m cells
    white = make_terrain("rough", correlation_length=0.0, seed=3).heights
    assert abs((white[:, 1:] * white[:, :-1]).mean() / (white * white).mean()) < 0.1


def test_long_range_world():
    hm = make_terrain("long_range", seed=0)
    xmin, xmax, ymin, ymax = hm.bounds
    assert xmax - xmin == pytest.approx(20.0 - hm.resolution) and ymax - ymin == pytest.approx(20.0 - hm.resolution)
    assert xmin < 0 < xmin + 2.5 and ymin < 0 < ymin + 2.5  # the start near a corner
    x, y = np.meshgrid(hm.x_coords, hm.y_coords)
    assert np.all(hm.heights[(x < 2) & (y < 2)] == 0.0)  # the start tile is flat
    assert hm.heights.max() > 0.2 and hm.heights.min() < -0.2  # stairs / boxes, and gaps / pits
    # Stairs: plateaus of many cells at a few levels; slopes and rough patches: many levels.
    assert len(np.unique(hm.heights)) > 1000


def test_material_floor_stripes_and_patches():
    floor = make_terrain("material_floor", patch_length=2.0)
    assert floor.material_at(0.0, 0.0) == "concrete"
    np.testing.assert_array_equal(floor.material_at(np.array([-1.5, 0.9, 1.1, 2.9, 3.1, 5.1]), 0.0),
                                  ["foam", "concrete", "wood", "wood", "foam", "concrete"])
    assert np.all(floor.heights == 0.0)
    checker = make_terrain("material_floor", materials=("wood", "foam"), patch_length=1.0, patch_width=1.0)
    np.testing.assert_array_equal(checker.material_at(np.array([0.0, 1.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0, 1.0])),
                                  ["wood", "foam", "foam", "wood"])
    with pytest.raises(TerrainError, match=r"terrain\.materials = \('wood', 'lava'\)"):
        make_terrain("material_floor", materials=("wood", "lava"))


def test_param_names():
    assert {"rise", "run", "count", "start_x", "size_x", "size_y", "resolution"} <= set(terrain_param_names("stairs"))
    assert "seed" not in terrain_param_names("gap")


@pytest.mark.parametrize("call, message", [
    (lambda: make_terrain("lava"), r"terrain\.kind = 'lava': unknown terrain kind \(valid: flat, slope, stairs"),
    (lambda: terrain_param_names("lava"), r"terrain\.kind = 'lava'"),
    (lambda: make_terrain("stairs", height=0.1), r"terrain\.height = 0\.1: not a parameter of stairs \(valid: rise"),
    (lambda: make_terrain("stairs", run=-0.4), r"terrain\.run = -0\.4"),
    (lambda: make_terrain("stairs", count=2.5), r"terrain\.count = 2\.5"),
    (lambda: make_terrain("stairs", rise="high"), r"terrain\.rise = 'high'"),
    (lambda: make_terrain("flat", resolution=0.0), r"terrain\.resolution = 0\.0"),
    (lambda: make_terrain("flat", size_x=float("nan")), r"terrain\.size_x = nan"),
    (lambda: make_terrain("slope", angle_deg=90), r"terrain\.angle_deg = 90"),
    (lambda: make_terrain("pits", depth=-0.1), r"terrain\.depth = -0\.1"),
    (lambda: make_terrain("obstacles", min_height=0.3, max_height=0.1), r"terrain\.max_height = 0\.1"),
    (lambda: make_terrain("obstacles", clear_radius=50.0), r"terrain\.clear_radius = 50\.0"),
    (lambda: make_terrain("flat", seed=-1), r"terrain\.seed = -1"),
])
def test_bad_terrain_input_names_the_field_and_value(call, message):
    with pytest.raises(TerrainError, match=message):
        call()


def test_whole_number_counts_from_yaml_floats():
    np.testing.assert_array_equal(make_terrain("stairs", count=3.0).heights, make_terrain("stairs", count=3).heights)


# The Drake contact geometry merges equal cells into boxes; the box-like generators must give
# it few, exact boxes.
def test_box_like_terrains_become_few_exact_boxes(tmp_path):
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    from qz_drake.terrain.drake_geometry import add_heightmap_to_plant, decompose_into_boxes

    def plant():
        return AddMultibodyPlantSceneGraph(DiagramBuilder(), 0.001)[0]

    assert len(decompose_into_boxes(make_terrain("stairs").heights)) == 3
    p = plant()
    assert add_heightmap_to_plant(p, make_terrain("stairs")) == "boxes"
    assert p.num_collision_geometries() == 3
    p = plant()
    assert add_heightmap_to_plant(p, make_terrain("rough"), mesh_dir=tmp_path) == "mesh"
    assert (tmp_path / "terrain_concrete.obj").stat().st_size > 1000
    hm = make_terrain("obstacles", seed=3)
    boxes = decompose_into_boxes(hm.heights)
    cover = np.zeros(hm.shape, dtype=int)
    for b in boxes:
        cover[b.iy0:b.iy1, b.ix0:b.ix1] += 1
        assert np.all(hm.heights[b.iy0:b.iy1, b.ix0:b.ix1] == b.height)
    assert np.all(cover == 1)
    floor = make_terrain("material_floor")
    assert len(decompose_into_boxes(floor.heights, floor.materials)) == 5  # stripes of x in [-2, 6]
