"""A mesh terrain as Drake geometry (qz_drake.terrain.drake_geometry): the contact mesh is the whole
surface, held in memory; what is drawn is the same surface with its planar rectangles merged, its
meshes meeting vertex to vertex."""

import hashlib
from pathlib import Path

import numpy as np
import pytest

from qz_drake.terrain import make_terrain
from qz_drake.terrain.drake_geometry import (_visual_band, drawn_surface_objs, heightmap_surface_obj,
                                             planar_rectangles)

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"
# sha256 of the demo world's contact mesh (long_range, seed 0).
CONTACT_MESH_SHA256 = "55c5a900d73e5612f39b5074bccc3c5ea28c098c615f4ad84929230e4be37902"


def _read_obj(text: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3), triangles (M, 3) of 0-based indices) of OBJ text."""
    lines = text.splitlines()
    vertices = np.array([line.split()[1:] for line in lines if line.startswith("v ")], dtype=float)
    faces = np.array([line.split()[1:] for line in lines if line.startswith("f ")], dtype=int) - 1
    return vertices, faces


def _band_masks(heightmap) -> list[np.ndarray]:
    """The quads of each height band, as add_heightmap_to_plant draws a map of one material."""
    h = heightmap.heights
    band = _visual_band(h)
    quad_band = np.floor(np.round((h[:-1, :-1] + h[:-1, 1:] + h[1:, :-1] + h[1:, 1:]) / 4.0 / band, 6))
    return [quad_band == index for index in np.unique(quad_band)]


def _cover(rectangles, shape) -> np.ndarray:
    count = np.zeros(shape, dtype=int)
    for iy0, iy1, ix0, ix1 in rectangles:
        count[iy0:iy1, ix0:ix1] += 1
    return count


def test_a_bump_keeps_its_four_quads_and_the_flat_rest_merges():
    heights = np.zeros((4, 4))
    heights[1, 1] = 1.0  # the four quads around cell (1, 1) are not planar
    rectangles = planar_rectangles(heights)
    assert sorted(map(tuple, rectangles.tolist())) == [
        (0, 1, 0, 1), (0, 1, 1, 2), (0, 2, 2, 3), (1, 2, 0, 1), (1, 2, 1, 2), (2, 3, 0, 3)]
    # A tilted plane is one rectangle; a mask keeps its quads only.
    x, y = np.meshgrid(np.arange(5), np.arange(4))
    assert planar_rectangles(0.1 * x - 0.05 * y).tolist() == [[0, 3, 0, 4]]
    mask = np.zeros((3, 4), dtype=bool)
    mask[1:, 2:] = True
    assert planar_rectangles(0.1 * x - 0.05 * y, mask).tolist() == [[1, 3, 2, 4]]


def test_the_demo_world_is_drawn_exactly_with_a_tenth_of_the_triangles():
    heightmap = make_terrain("long_range", seed=0)
    h = heightmap.heights
    rectangles = planar_rectangles(h)
    np.testing.assert_array_equal(_cover(rectangles, (h.shape[0] - 1, h.shape[1] - 1)), 1)
    merged = rectangles[(rectangles[:, 1] - rectangles[:, 0]) * (rectangles[:, 3] - rectangles[:, 2]) > 1]
    assert len(merged) > 500
    for iy0, iy1, ix0, ix1 in merged:
        # Every cell centre of a merged rectangle lies on the plane through its corners (a
        # single quad is split as the contact mesh splits it).
        rows, cols = np.arange(iy1 - iy0 + 1)[:, None], np.arange(ix1 - ix0 + 1)[None, :]
        plane = (h[iy0, ix0] + rows / (iy1 - iy0) * (h[iy1, ix0] - h[iy0, ix0])
                 + cols / (ix1 - ix0) * (h[iy0, ix1] - h[iy0, ix0]))
        np.testing.assert_allclose(h[iy0:iy1 + 1, ix0:ix1 + 1], plane, atol=1e-4)
    contact = heightmap_surface_obj(heightmap)
    triangles = sum(text.count("\nf ") for text in drawn_surface_objs(heightmap, _band_masks(heightmap)))
    assert 2 * len(rectangles) < triangles < contact.count("\nf ") / 8
    # The contact mesh is the one the demo has always walked on.
    assert hashlib.sha256(contact.encode()).hexdigest() == CONTACT_MESH_SHA256


def test_the_terrain_meshes_stay_in_memory_and_collide_as_the_files_did(tmp_path):
    from qz_drake.config import load_scenario
    from qz_drake.simulation import simulate
    from qz_drake.station import make_station

    scenario = load_scenario(SCENARIOS / "stand_grid_map.yaml")
    in_memory = simulate(scenario, duration=0.3, out_dir=tmp_path / "run")
    assert in_memory.metrics["terrain_contact"] == "mesh"
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [
        "base_and_contacts.png", "metrics.json", "recording.html"]

    def from_files(scenario, meshcat, **kwargs):
        return make_station(scenario, meshcat, mesh_dir=tmp_path / "meshes", **kwargs)

    on_disk = simulate(scenario, duration=0.3, station_factory=from_files)
    assert (tmp_path / "meshes" / "terrain_concrete.obj").is_file()
    np.testing.assert_array_equal(in_memory.states, on_disk.states)


@pytest.mark.parametrize("kind", ["stairs", "slope", "rough"])
def test_the_drawn_surface_covers_what_the_contact_surface_covers(kind):
    heightmap = make_terrain(kind)
    vertices, faces = _read_obj(drawn_surface_objs(heightmap, [None])[0])
    a, b, c = (vertices[faces[:, k], :2] for k in range(3))
    area = 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    assert np.all(area > 0)  # counter-clockwise from above: normals up
    quads = (heightmap.heights.shape[0] - 1) * (heightmap.heights.shape[1] - 1)
    assert area.sum() == pytest.approx(quads * heightmap.resolution ** 2)
    cells = (vertices[:, :2] - heightmap.origin) / heightmap.resolution
    on_grid = np.all(np.abs(cells - np.round(cells)) < 1e-6, axis=1)  # (a fan's centre need not be)
    np.testing.assert_allclose(vertices[on_grid, 2], heightmap.height(vertices[on_grid, 0], vertices[on_grid, 1]),
                               atol=1e-6)


def test_the_drawn_meshes_meet_vertex_to_vertex():
    # A vertex of one mesh inside an edge of another (a T-junction) leaves a crack of single
    # pixels along the edge, the sky showing through.
    heightmap = make_terrain("long_range", seed=0)
    H, W = heightmap.heights.shape
    meshes = []
    for text in drawn_surface_objs(heightmap, _band_masks(heightmap)):
        vertices, faces = _read_obj(text)
        cells = (vertices[:, :2] - heightmap.origin) / heightmap.resolution
        grid = np.where(np.all(np.abs(cells - np.round(cells)) < 1e-6, axis=1, keepdims=True),
                        np.round(cells), np.nan)
        meshes.append(grid[faces])  # (M, 3, 2) cell coordinates (x, y) of each corner, NaN off the grid
    used = np.zeros((H, W), dtype=bool)
    for corners in meshes:
        ix, iy = corners.reshape(-1, 2)[~np.isnan(corners.reshape(-1, 2)).any(axis=1)].astype(int).T
        used[iy, ix] = True
    along_x, along_y = np.cumsum(used, axis=1), np.cumsum(used, axis=0)
    edges = np.concatenate([np.concatenate([corners[:, k], corners[:, (k + 1) % 3]], axis=1)
                            for corners in meshes for k in range(3)])
    edges = edges[~np.isnan(edges).any(axis=1)].astype(int)  # (x0, y0, x1, y1)
    rows = edges[edges[:, 1] == edges[:, 3]]
    x0, x1 = np.minimum(rows[:, 0], rows[:, 2]), np.maximum(rows[:, 0], rows[:, 2])
    columns = edges[edges[:, 0] == edges[:, 2]]
    y0, y1 = np.minimum(columns[:, 1], columns[:, 3]), np.maximum(columns[:, 1], columns[:, 3])
    assert len(rows) > 1000 and len(columns) > 1000
    assert np.all(along_x[rows[:, 1], np.maximum(x1 - 1, x0)] - along_x[rows[:, 1], x0] == 0)
    assert np.all(along_y[np.maximum(y1 - 1, y0), columns[:, 0]] - along_y[y0, columns[:, 0]] == 0)
