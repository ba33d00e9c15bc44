"""HeightMap interpolation, normals, patches, files; the real grid_map image."""

import math
from pathlib import Path

import numpy as np
import pytest

from qz_drake.errors import TerrainError
from qz_drake.terrain import HeightMap, grid_map_terrain

GRID_MAP_PNG = Path(__file__).resolve().parents[3] / "shared" / "data" / "grid_map" / "terrain.png"


def _small():
    # Centres at x = 1.0, 1.5, 2.0 and y = -1.0, -0.5, 0.0.
    heights = np.array([[0.0, 1.0, 2.0], [1.0, 2.0, 3.0], [0.0, 0.0, 4.0]])
    return HeightMap(heights, 0.5, (1.0, -1.0))


def test_bilinear_height_by_hand():
    hm = _small()
    assert hm.height(1.0, -1.0) == 0.0
    assert hm.height(1.25, -1.0) == pytest.approx(0.5)
    # Centre of the upper-right quad: mean of its four corners (2, 3, 0, 4).
    assert hm.height(1.75, -0.25) == pytest.approx(2.25)
    # Clamped outside the map.
    assert hm.height(10.0, 10.0) == 4.0
    np.testing.assert_allclose(hm.height(np.array([1.0, 1.25]), np.array([-1.0, -1.0])), [0.0, 0.5])


def test_gradient_is_the_exact_derivative_of_the_interpolant():
    hm = HeightMap(np.random.default_rng(0).normal(size=(6, 7)), 0.1, (0.3, -0.2))
    rng = np.random.default_rng(1)
    x = rng.uniform(0.31, 0.89, 50)
    y = rng.uniform(-0.19, 0.29, 50)
    dx, dy = hm.gradient(x, y)
    eps = 1e-7
    # Inside a cell the interpolant is smooth: central differences agree.
    np.testing.assert_allclose(dx, (hm.height(x + eps, y) - hm.height(x - eps, y)) / (2 * eps), atol=1e-5)
    np.testing.assert_allclose(dy, (hm.height(x, y + eps) - hm.height(x, y - eps)) / (2 * eps), atol=1e-5)


def test_normals_of_a_slope():
    angle = math.radians(20)
    xs = np.arange(10) * 0.1
    heights = np.tile(xs * math.tan(angle), (8, 1))
    hm = HeightMap(heights, 0.1)
    n = hm.normal(np.array([0.33, 0.5]), np.array([0.2, 0.4]))
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0)
    np.testing.assert_allclose(n[0], [-math.sin(angle), 0.0, math.cos(angle)], atol=1e-12)


@pytest.mark.parametrize("yaw", [0.0, 0.4, math.pi / 2, -2.0])
def test_patch_of_a_plane_is_the_plane(yaw):
    a, b = 0.2, -0.1
    xs = np.arange(-50, 51) * 0.05
    X, Y = np.meshgrid(xs, xs)
    hm = HeightMap(a * X + b * Y, 0.05, (xs[0], xs[0]))
    n, spacing = 5, 0.1
    patch = hm.patch(0.3, -0.2, yaw, n, spacing)
    offsets = (np.arange(n) - 2) * spacing
    U, V = np.meshgrid(offsets, offsets, indexing="ij")
    wx = 0.3 + math.cos(yaw) * U - math.sin(yaw) * V
    wy = -0.2 + math.sin(yaw) * U + math.cos(yaw) * V
    np.testing.assert_allclose(patch, a * wx + b * wy, atol=1e-12)
    batch = hm.patch(np.zeros(4), np.zeros(4), np.full(4, yaw), n, spacing)
    assert batch.shape == (4, n, n)


def test_npz_and_png_round_trips(tmp_path):
    hm = HeightMap(np.random.default_rng(2).uniform(0, 0.3, (12, 9)), 0.05, (-0.2, 0.4),
                   np.random.default_rng(3).integers(0, 2, (12, 9)), ("concrete", "foam"))
    hm.save_npz(tmp_path / "m.npz")
    back = HeightMap.load(tmp_path / "m.npz")
    np.testing.assert_array_equal(back.heights, hm.heights)
    np.testing.assert_array_equal(back.materials, hm.materials)
    assert back.material_names == hm.material_names and back.origin == hm.origin
    meta = hm.save_png(tmp_path / "m.png")
    again = HeightMap.load(meta)
    np.testing.assert_allclose(again.heights, hm.heights, atol=0.3 / 65535 + 1e-12)
    assert again.origin == pytest.approx(hm.origin) and again.resolution == hm.resolution


@pytest.mark.parametrize("kwargs, field", [
    (dict(heights=np.array([[0.0, np.nan], [0.0, 0.0]]), resolution=0.1), r"heightmap.heights\[0, 1\] = nan"),
    (dict(heights=np.zeros((3, 3)), resolution=0.0), "heightmap.resolution = 0.0"),
    (dict(heights=np.zeros((3, 3)), resolution=-0.1), "heightmap.resolution = -0.1"),
    (dict(heights=np.zeros(5), resolution=0.1), "heightmap.heights"),
])
def test_bad_maps_name_the_field(kwargs, field):
    with pytest.raises(TerrainError, match=field):
        HeightMap(**kwargs)


def test_real_grid_map_image():
    hm = HeightMap.from_image(GRID_MAP_PNG, 0.05, 0.0, 0.4)
    assert hm.shape == (500, 500)
    assert 0.0 <= hm.heights.min() and hm.heights.max() <= 0.4 and hm.heights.std() > 0.01
    # North up: image row 0 is the largest y.
    from PIL import Image

    pixels = np.asarray(Image.open(GRID_MAP_PNG))[..., 0]
    np.testing.assert_allclose(hm.heights[-1], pixels[0] / 255 * 0.4)
    # The packaged copy is the same map, centred on the origin.
    packaged = grid_map_terrain()
    np.testing.assert_array_equal(packaged.heights, hm.heights)
    assert packaged.height(0.0, 0.0) == pytest.approx(hm.height(0.0, 0.0))
    assert packaged.bounds[0] == pytest.approx(-packaged.bounds[1])
