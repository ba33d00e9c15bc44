"""HeightMap: interpolation by hand, gradients, normals, patches, files, the real grid_map images."""

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from qz_drake.errors import TerrainError
from qz_drake.terrain import HeightMap, grid_map_terrain

REPO = Path(__file__).resolve().parents[2]
# grid_map's demo pictures: terrain.png ships with the package, heightmap_generated.png serves
# the scenarios (data/external/grid_map/SOURCE.md).
PACKAGED = REPO / "qz_drake" / "data"
EXTERNAL = REPO / "data" / "external" / "grid_map"
TERRAIN_PNG = PACKAGED / "grid_map_terrain.png"
GENERATED_PNG = EXTERNAL / "heightmap_generated.png"


def _small():
    # Centres at x = 1.0, 1.5, 2.0 (columns) and y = -1.0, -0.5, 0.0 (rows).
    heights = np.array([[0.0, 1.0, 2.0],
                        [1.0, 2.0, 3.0],
                        [0.0, 0.0, 4.0]])
    return HeightMap(heights, 0.5, (1.0, -1.0))


def test_grid_geometry_by_hand():
    hm = _small()
    assert hm.shape == (3, 3)
    np.testing.assert_array_equal(hm.x_coords, [1.0, 1.5, 2.0])
    np.testing.assert_array_equal(hm.y_coords, [-1.0, -0.5, 0.0])
    assert hm.bounds == (1.0, 2.0, -1.0, 0.0)
    np.testing.assert_array_equal(hm.contains([1.0, 2.0, 2.01, 1.5], [-1.0, 0.0, -0.5, 0.01]),
                                  [True, True, False, False])
    ix, iy = hm.index(np.array([1.24, 1.26, 9.0, -9.0]), np.array([-1.0, -0.74, -0.76, 0.0]))
    np.testing.assert_array_equal(ix, [0, 1, 2, 0])
    np.testing.assert_array_equal(iy, [0, 1, 0, 2])


def test_bilinear_height_by_hand():
    hm = _small()
    assert hm.height(1.0, -1.0) == 0.0
    assert hm.height(1.25, -1.0) == pytest.approx(0.5)
    assert hm.height(1.5, -0.75) == pytest.approx(1.5)
    # Centre of the upper-right quad: the mean of its corners 2, 3, 0, 4.
    assert hm.height(1.75, -0.25) == pytest.approx(2.25)
    # A quarter into the quad from its lower-left corner: 2*9/16 + 3*3/16 + 0*3/16 + 4*1/16.
    assert hm.height(1.625, -0.375) == pytest.approx((18 + 9 + 4) / 16)
    # Clamped to the border outside: the corner, and the top edge straight above.
    assert hm.height(10.0, 10.0) == 4.0
    assert hm.height(1.75, 5.0) == pytest.approx(2.0)
    # Broadcasting: (2, 1) x (3,) -> (2, 3).
    z = hm.height(np.array([[1.0], [1.5]]), np.array([-1.0, -0.5, 0.0]))
    np.testing.assert_allclose(z, [[0.0, 1.0, 0.0], [1.0, 2.0, 0.0]])
    assert np.isnan(hm.height(np.nan, 0.0))


def test_gradient_by_hand():
    hm = _small()
    # Upper-right quad, h00 = 2, h10 = 3, h01 = 0, h11 = 4 over 0.5 m.
    dx, dy = hm.gradient(1.75, -0.25)
    assert dx == pytest.approx(((3 - 2) * 0.5 + (4 - 0) * 0.5) / 0.5)  # 5
    assert dy == pytest.approx(((0 - 2) * 0.5 + (4 - 3) * 0.5) / 0.5)  # -1
    # Above the map: y is clamped (dh/dy = 0), x still varies along the top row 0, 0, 4.
    dx, dy = hm.gradient(1.75, 5.0)
    assert (dx, dy) == (pytest.approx(8.0), 0.0)
    assert hm.gradient(-5.0, -5.0) == (0.0, 0.0)


def test_gradient_is_the_exact_derivative_of_the_interpolant():
    hm = HeightMap(np.random.default_rng(0).normal(size=(6, 7)), 0.1, (0.3, -0.2))
    rng = np.random.default_rng(1)
    # Keep off the quad borders, where the interpolant has kinks.
    x = 0.3 + 0.1 * (rng.integers(0, 6, 50) + rng.uniform(0.05, 0.95, 50))
    y = -0.2 + 0.1 * (rng.integers(0, 5, 50) + rng.uniform(0.05, 0.95, 50))
    dx, dy = hm.gradient(x, y)
    eps = 1e-6
    np.testing.assert_allclose(dx, (hm.height(x + eps, y) - hm.height(x - eps, y)) / (2 * eps), atol=1e-6)
    np.testing.assert_allclose(dy, (hm.height(x, y + eps) - hm.height(x, y - eps)) / (2 * eps), atol=1e-6)


def test_normals_of_a_slope_of_known_angle():
    angle = math.radians(20)
    xs = np.arange(10) * 0.1
    hm = HeightMap(np.tile(xs * math.tan(angle), (8, 1)), 0.1)
    n = hm.normal(np.array([0.33, 0.5, 0.81]), np.array([0.2, 0.4, 0.05]))
    assert n.shape == (3, 3)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0)
    np.testing.assert_allclose(n, np.tile([-math.sin(angle), 0.0, math.cos(angle)], (3, 1)), atol=1e-12)
    # Tilted the other way along y.
    hm_y = HeightMap(np.tile((xs[:8] * -math.tan(angle))[:, None], (1, 10)), 0.1)
    np.testing.assert_allclose(hm_y.normal(0.4, 0.35), [0.0, math.sin(angle), math.cos(angle)], atol=1e-12)


@pytest.mark.parametrize("yaw", [0.0, 0.4, math.pi / 2, -2.0])
def test_patch_of_a_plane_is_the_plane(yaw):
    a, b = 0.2, -0.1
    xs = np.arange(-50, 51) * 0.05
    X, Y = np.meshgrid(xs, xs)
    hm = HeightMap(a * X + b * Y, 0.05, (xs[0], xs[0]))
    n, spacing = 5, 0.1
    patch = hm.patch(0.3, -0.2, yaw, n, spacing)
    assert patch.shape == (n, n)
    offsets = (np.arange(n) - 2) * spacing
    U, V = np.meshgrid(offsets, offsets, indexing="ij")
    wx = 0.3 + math.cos(yaw) * U - math.sin(yaw) * V
    wy = -0.2 + math.sin(yaw) * U + math.cos(yaw) * V
    np.testing.assert_allclose(patch, a * wx + b * wy, atol=1e-12)


def test_patch_orientation_and_batch():
    xs = np.arange(-40, 41) * 0.05
    X, Y = np.meshgrid(xs, xs)
    hm = HeightMap(Y.copy(), 0.05, (xs[0], xs[0]))  # h = y
    # Facing +y (yaw 90 deg), body x points along world +y: row i grows with i.
    patch = hm.patch(0.0, 0.5, math.pi / 2, 3, 0.2)
    np.testing.assert_allclose(patch[:, 1], [0.3, 0.5, 0.7], atol=1e-12)
    # Body +y (column j) then points along world -x, where h = y does not change.
    np.testing.assert_allclose(patch[1, :], [0.5, 0.5, 0.5], atol=1e-12)
    batch = hm.patch(np.zeros(4), np.linspace(-1, 1, 4), np.full(4, math.pi / 2), 20, 0.1)
    assert batch.shape == (4, 20, 20)
    np.testing.assert_allclose(batch[3], hm.patch(0.0, 1.0, math.pi / 2, 20, 0.1))
    with pytest.raises(TerrainError, match="patch.n = 0"):
        hm.patch(0.0, 0.0, 0.0, 0, 0.1)


def test_materials_and_crop():
    heights = np.arange(20.0).reshape(4, 5)
    labels = np.array([[0, 0, 1, 1, 1]] * 4)
    hm = HeightMap(heights, 0.5, (0.0, 0.0), labels, ("concrete", "foam"))
    assert hm.material_at(0.2, 1.0) == "concrete"
    np.testing.assert_array_equal(hm.material_at([0.74, 0.76, 5.0], [0.0, 0.0, 0.0]), ["concrete", "foam", "foam"])
    sub = hm.crop(0.5, 1.5, 0.4, 1.5)
    assert sub.origin == (0.5, 0.5) and sub.shape == (3, 3)
    np.testing.assert_array_equal(sub.heights, heights[1:4, 1:4])
    np.testing.assert_array_equal(sub.materials, labels[1:4, 1:4])
    with pytest.raises(TerrainError, match="heightmap.crop"):
        hm.crop(5.0, 6.0, 0.0, 1.0)
    with pytest.raises(TerrainError, match="heightmap.materials = None"):
        _small().material_at(1.0, -1.0)


def test_npz_and_png_yaml_round_trips(tmp_path):
    rng = np.random.default_rng(2)
    hm = HeightMap(rng.uniform(-0.1, 0.3, (12, 9)), 0.05, (-0.2, 0.4),
                   rng.integers(0, 3, (12, 9)), ("concrete", "wood", "foam"))
    path = hm.save_npz(tmp_path / "m.npz")
    back = HeightMap.load(path)
    np.testing.assert_array_equal(back.heights, hm.heights)
    np.testing.assert_array_equal(back.materials, hm.materials)
    assert back.material_names == hm.material_names and back.origin == hm.origin
    assert back.resolution == hm.resolution
    meta = hm.save_png(tmp_path / "m.png")
    assert meta == tmp_path / "m.yaml"
    again = HeightMap.load(meta)
    span = hm.heights.max() - hm.heights.min()
    assert np.abs(again.heights - hm.heights).max() <= span / 65535
    assert again.origin == pytest.approx(hm.origin) and again.resolution == hm.resolution
    np.testing.assert_array_equal(again.materials, hm.materials)
    # North up: the picture's top row is the map's last row (largest y).
    pixels = np.asarray(Image.open(tmp_path / "m.png"))
    assert pixels.dtype == np.uint16
    np.testing.assert_array_equal(pixels[0], np.rint((hm.heights[-1] - hm.heights.min()) / span * 65535))


def test_from_image_orientation_and_scaling(tmp_path):
    pixels = np.zeros((3, 4), np.uint8)
    pixels[0, :] = 255  # top row of the picture
    pixels[2, 3] = 51
    Image.fromarray(pixels).save(tmp_path / "p.png")
    hm = HeightMap.from_image(tmp_path / "p.png", 0.1, -0.1, 0.4)
    assert hm.shape == (3, 4)
    np.testing.assert_allclose(hm.heights[-1], 0.4)  # largest y
    assert hm.heights[0, 3] == pytest.approx(-0.1 + 51 / 255 * 0.5)
    # Centred on the origin: centres from -0.15 to 0.15 along x, -0.1 to 0.1 along y.
    assert hm.bounds == pytest.approx((-0.15, 0.15, -0.1, 0.1))
    assert hm.height(0.0, 0.1) == pytest.approx(0.4)


def test_real_grid_map_terrain_png():
    hm = HeightMap.from_image(TERRAIN_PNG, 0.05, 0.0, 0.4)
    assert hm.shape == (500, 500)
    assert 0.0 <= hm.heights.min() and hm.heights.max() <= 0.4 and hm.heights.std() > 0.05
    rgba = np.asarray(Image.open(TERRAIN_PNG))
    assert rgba.shape == (500, 500, 4) and rgba.dtype == np.uint8
    # North up: the image's top row is the largest y; transparent pixels (no data) are lowest.
    opaque = rgba[..., 3] >= 128
    np.testing.assert_allclose(hm.heights[-1], np.where(opaque[0], rgba[0, :, 0] / 255 * 0.4, 0.0))
    np.testing.assert_allclose(hm.heights[::-1][opaque], rgba[..., 0][opaque] / 255 * 0.4)
    assert np.all(hm.heights[::-1][~opaque] == 0.0)
    row, col = 100, 120  # a pixel in the top-left quarter maps to negative x, positive y
    x, y = hm.x_coords[col], hm.y_coords[499 - row]
    assert x < 0 < y and hm.height(x, y) == pytest.approx(hm.heights[::-1][row, col])


def test_real_16_bit_rgb_png():
    hm = HeightMap.from_image(GENERATED_PNG, 0.1, 0.0, 1.0)
    assert hm.shape == (195, 250)
    assert 0.0 <= hm.heights.min() and hm.heights.max() <= 1.0
    # PIL reads only the high byte of each 16-bit sample; our decoder keeps both.
    high_byte = np.asarray(Image.open(GENERATED_PNG))[..., 0][::-1].astype(float)
    np.testing.assert_array_equal(np.floor(hm.heights * 65535 / 256 + 1e-9), high_byte)
    assert len(np.unique(np.rint(hm.heights * 65535).astype(int) % 256)) > 100


def test_packaged_grid_map_copy():
    # Its bytes are checked against grid_map's in tests/test_self_contained.py.
    assert (PACKAGED / "GRID_MAP_LICENSE").read_bytes() == (EXTERNAL / "LICENSE").read_bytes()
    packaged = grid_map_terrain()
    np.testing.assert_array_equal(packaged.heights, HeightMap.from_image(TERRAIN_PNG, 0.05, 0.0, 0.4).heights)
    assert packaged.bounds == pytest.approx((-12.475, 12.475, -12.475, 12.475))


@pytest.mark.parametrize("kwargs, field", [
    (dict(heights=np.array([[0.0, 0.0], [np.nan, 0.0]]), resolution=0.1), r"heightmap\.heights\[1, 0\] = nan"),
    (dict(heights=np.zeros((3, 3)), resolution=0.0), r"heightmap\.resolution = 0\.0"),
    (dict(heights=np.zeros((3, 3)), resolution=-0.1), r"heightmap\.resolution = -0\.1"),
    (dict(heights=np.zeros((3, 3)), resolution=float("inf")), r"heightmap\.resolution = inf"),
    (dict(heights=np.zeros(5), resolution=0.1), r"heightmap\.heights = 'array of shape \(5,\)'"),
    (dict(heights=np.zeros((1, 4)), resolution=0.1), r"heightmap\.heights"),
    (dict(heights=np.zeros((2, 2)), resolution=0.1, origin=(0.0, np.nan)), r"heightmap\.origin = nan"),
    (dict(heights=np.zeros((2, 2)), resolution=0.1, materials=np.zeros((3, 2), int), material_names=("wood",)),
     r"heightmap\.materials = 'array of shape \(3, 2\)'"),
    (dict(heights=np.zeros((2, 2)), resolution=0.1, materials=np.ones((2, 2), int), material_names=("wood",)),
     r"heightmap\.materials = 'labels 1\.\.1'"),
])
def test_bad_maps_name_the_field_and_value(kwargs, field):
    with pytest.raises(TerrainError, match=field):
        HeightMap(**kwargs)


def test_bad_files_name_the_field(tmp_path):
    with pytest.raises(TerrainError, match="heightmap.file = .*missing.npz.*no such file"):
        HeightMap.load(tmp_path / "missing.npz")
    with pytest.raises(TerrainError, match="heightmap.file = .*m.txt"):
        HeightMap.load(tmp_path / "m.txt")
    (tmp_path / "bad.yaml").write_text("image: x.png\nresolution: 0.1\n")
    with pytest.raises(TerrainError, match="heightmap.min_height"):
        HeightMap.load(tmp_path / "bad.yaml")
    with pytest.raises(TerrainError, match="heightmap.max_height = -1"):
        HeightMap.from_image(PACKAGED / "grid_map_terrain.png", 0.05, 0.0, -1)
