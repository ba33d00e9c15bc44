"""Generators make the terrain their names promise; materials; box decomposition."""

import math

import numpy as np
import pytest
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder

from qz_drake.errors import TerrainError
from qz_drake.terrain import TERRAIN_KINDS, get_material, make_terrain
from qz_drake.terrain.drake_geometry import add_heightmap_to_plant, decompose_into_boxes


@pytest.mark.parametrize("kind", sorted(TERRAIN_KINDS))
def test_every_generator_is_finite_seeded_and_flat_at_the_start(kind):
    a = make_terrain(kind, seed=1)
    b = make_terrain(kind, seed=1)
    np.testing.assert_array_equal(a.heights, b.heights)
    assert np.isfinite(a.heights).all()
    assert a.contains(0.0, 0.0)
    if kind not in ("waves", "rough"):
        assert abs(a.height(0.0, 0.0)) < 1e-9, kind


@pytest.mark.parametrize("kind", ["rough", "obstacles", "pits", "long_range"])
def test_random_generators_differ_across_seeds(kind):
    assert not np.array_equal(make_terrain(kind, seed=1).heights, make_terrain(kind, seed=2).heights)


def test_stairs_rise_run_and_edges_on_cell_boundaries():
    hm = make_terrain("stairs", rise=0.1, run=0.4, count=2, start_x=0.5)
    assert hm.height(0.45, 0.0) == 0.0
    assert hm.height(0.7, 0.0) == pytest.approx(0.1)
    assert hm.height(1.1, 0.0) == pytest.approx(0.2)
    assert hm.height(3.0, 0.0) == pytest.approx(0.2)
    # Piecewise constant: three heights, three boxes.
    assert sorted(np.unique(hm.heights)) == pytest.approx([0.0, 0.1, 0.2])
    assert len(decompose_into_boxes(hm.heights)) == 3


def test_gap_slope_and_step():
    gap = make_terrain("gap", gap_width=0.3, depth=0.5, start_x=0.6)
    assert gap.height(0.75, 0.0) == pytest.approx(-0.5) and gap.height(1.0, 0.0) == 0.0
    slope = make_terrain("slope", angle_deg=15.0, start_x=0.5)
    dx, dy = slope.gradient(2.0, 0.3)
    assert math.degrees(math.atan(dx)) == pytest.approx(15.0) and dy == 0.0
    step = make_terrain("step", height=0.2, start_x=0.5, depth=0.6)
    assert step.height(0.8, 0.0) == pytest.approx(0.2) and step.height(1.3, 0.0) == 0.0


def test_material_floor_labels_stripes():
    floor = make_terrain("material_floor", patch_length=2.0)
    assert floor.material_at(-1.0, 0.0) == "concrete"
    assert floor.material_at(1.0, 0.0) == "wood"
    assert floor.material_at(3.0, 0.0) == "foam"


def test_materials_order_by_stiffness():
    assert get_material("concrete").stiffness > 300e3
    assert get_material("foam").stiffness == pytest.approx(20e3)
    assert get_material("foam").stiffness < get_material("wood").stiffness < get_material("concrete").stiffness


@pytest.mark.parametrize("call, field", [
    (lambda: make_terrain("lava"), "terrain.kind = 'lava'"),
    (lambda: make_terrain("stairs", height=0.1), "terrain.height"),
    (lambda: make_terrain("stairs", run=-0.4), "terrain.run = -0.4"),
    (lambda: make_terrain("flat", resolution=0.0), "terrain.resolution = 0.0"),
    (lambda: get_material("ice"), "material = 'ice'"),
])
def test_bad_terrain_input_names_the_field(call, field):
    with pytest.raises(TerrainError, match=field.replace(".", r"\.").replace("(", r"\(")):
        call()


def _plant():
    plant, _ = AddMultibodyPlantSceneGraph(DiagramBuilder(), 0.001)
    return plant


def test_contact_geometry_choice(tmp_path):
    plant = _plant()
    assert add_heightmap_to_plant(plant, make_terrain("stairs")) == "boxes"
    assert plant.num_collision_geometries() == 3
    plant = _plant()
    assert add_heightmap_to_plant(plant, make_terrain("rough"), mesh_dir=tmp_path) == "mesh"
    assert (tmp_path / "terrain_concrete.obj").stat().st_size > 1000
    with pytest.raises(TerrainError, match="terrain.contact"):
        add_heightmap_to_plant(_plant(), make_terrain("rough"), contact="boxes")
    # Boxes cover the map exactly: every cell in exactly one box.
    hm = make_terrain("obstacles", seed=3)
    boxes = decompose_into_boxes(hm.heights)
    cover = np.zeros(hm.shape, dtype=int)
    for b in boxes:
        cover[b.iy0:b.iy1, b.ix0:b.ix1] += 1
        assert np.all(hm.heights[b.iy0:b.iy1, b.ix0:b.ix1] == b.height)
    assert np.all(cover == 1)
