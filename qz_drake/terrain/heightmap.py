"""HeightMap: a regular grid of terrain heights, the way grid_map and map servers store them.

Cell (ix, iy) has its centre at x = origin[0] + ix * resolution, y = origin[1] + iy * resolution
and its height in ``heights[iy, ix]``. Between centres the height is bilinear; outside the map
it is clamped to the border (the map's edge extends as a plateau), which keeps every query
defined for planners that peek past the edge.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import yaml

from qz_drake.errors import TerrainError, bad_value


@dataclasses.dataclass
class HeightMap:
    """Terrain heights on a regular grid, with optional per-cell ground material labels."""

    # (H, W) heights [m]; heights[iy, ix] is the height at the centre of cell (ix, iy).
    heights: np.ndarray
    # Cell size. [m]
    resolution: float
    # World (x, y) of the centre of cell (0, 0). [m]
    origin: tuple[float, float] = (0.0, 0.0)
    # (H, W) indices into material_names, or None for a single material.
    materials: np.ndarray | None = None
    # Names of the materials the labels index (see qz_drake.terrain.materials).
    material_names: tuple[str, ...] = ()

    def __post_init__(self):
        h = np.asarray(self.heights, dtype=float)
        if h.ndim != 2 or h.shape[0] < 2 or h.shape[1] < 2:
            raise bad_value("heightmap.heights", f"array of shape {h.shape}",
                            "expected a 2-D array of at least 2 x 2 cells", TerrainError)
        bad = ~np.isfinite(h)
        if bad.any():
            iy, ix = np.argwhere(bad)[0]
            raise bad_value(f"heightmap.heights[{iy}, {ix}]", float(h[iy, ix]),
                            "heights must be finite", TerrainError)
        self.heights = h
        try:
            res = float(self.resolution)
        except (TypeError, ValueError):
            raise bad_value("heightmap.resolution", self.resolution, "not a number", TerrainError) from None
        if not (math.isfinite(res) and res > 0):
            raise bad_value("heightmap.resolution", self.resolution, "must be finite and positive",
                            TerrainError)
        self.resolution = res
        origin = tuple(float(v) for v in np.asarray(self.origin, dtype=float).reshape(-1))
        if len(origin) != 2 or not all(math.isfinite(v) for v in origin):
            raise bad_value("heightmap.origin", self.origin, "expected two finite numbers", TerrainError)
        self.origin = origin
        self.material_names = tuple(str(n) for n in self.material_names)
        if self.materials is not None:
            m = np.asarray(self.materials)
            if m.shape != h.shape:
                raise bad_value("heightmap.materials", f"array of shape {m.shape}",
                                f"must have the heights' shape {h.shape}", TerrainError)
            if m.size and (m.min() < 0 or m.max() >= len(self.material_names)):
                raise bad_value("heightmap.materials", f"labels {m.min()}..{m.max()}",
                                f"must index material_names {self.material_names}", TerrainError)
            self.materials = m.astype(np.int64)

    # -- geometry ---------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return self.heights.shape

    @property
    def x_coords(self) -> np.ndarray:
        return self.origin[0] + self.resolution * np.arange(self.heights.shape[1])

    @property
    def y_coords(self) -> np.ndarray:
        return self.origin[1] + self.resolution * np.arange(self.heights.shape[0])

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the cell centres. [m]"""
        H, W = self.heights.shape
        return (self.origin[0], self.origin[0] + (W - 1) * self.resolution,
                self.origin[1], self.origin[1] + (H - 1) * self.resolution)

    def contains(self, x, y) -> np.ndarray:
        xmin, xmax, ymin, ymax = self.bounds
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)

    def index(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Nearest cell (ix, iy), clamped to the map."""
        H, W = self.heights.shape
        ix = np.clip(np.rint((np.asarray(x, dtype=float) - self.origin[0]) / self.resolution), 0, W - 1)
        iy = np.clip(np.rint((np.asarray(y, dtype=float) - self.origin[1]) / self.resolution), 0, H - 1)
        return ix.astype(np.int64), iy.astype(np.int64)

    def _cell(self, x, y):
        """Lower-left cell indices and fractions for bilinear interpolation (clamped)."""
        H, W = self.heights.shape
        u = np.clip((np.asarray(x, dtype=float) - self.origin[0]) / self.resolution, 0.0, W - 1.0)
        v = np.clip((np.asarray(y, dtype=float) - self.origin[1]) / self.resolution, 0.0, H - 1.0)
        i0 = np.minimum(np.floor(u).astype(np.int64), W - 2)
        j0 = np.minimum(np.floor(v).astype(np.int64), H - 2)
        inside_x = ((np.asarray(x, dtype=float) - self.origin[0]) / self.resolution >= 0) & (
            (np.asarray(x, dtype=float) - self.origin[0]) / self.resolution <= W - 1)
        inside_y = ((np.asarray(y, dtype=float) - self.origin[1]) / self.resolution >= 0) & (
            (np.asarray(y, dtype=float) - self.origin[1]) / self.resolution <= H - 1)
        return i0, j0, u - i0, v - j0, inside_x, inside_y

    def height(self, x, y) -> np.ndarray:
        """Bilinear height at world (x, y), vectorised with broadcasting. [m]"""
        i0, j0, fx, fy, _, _ = self._cell(x, y)
        h = self.heights
        h00, h10 = h[j0, i0], h[j0, i0 + 1]
        h01, h11 = h[j0 + 1, i0], h[j0 + 1, i0 + 1]
        return (h00 * (1 - fx) * (1 - fy) + h10 * fx * (1 - fy) + h01 * (1 - fx) * fy + h11 * fx * fy)

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Exact derivative (dh/dx, dh/dy) of the bilinear interpolant; zero across a clamped
        direction outside the map."""
        i0, j0, fx, fy, inside_x, inside_y = self._cell(x, y)
        h = self.heights
        h00, h10 = h[j0, i0], h[j0, i0 + 1]
        h01, h11 = h[j0 + 1, i0], h[j0 + 1, i0 + 1]
        dx = ((h10 - h00) * (1 - fy) + (h11 - h01) * fy) / self.resolution
        dy = ((h01 - h00) * (1 - fx) + (h11 - h10) * fx) / self.resolution
        return np.where(inside_x, dx, 0.0), np.where(inside_y, dy, 0.0)

    def normal(self, x, y) -> np.ndarray:
        """Unit surface normals (..., 3)."""
        dx, dy = self.gradient(x, y)
        n = np.stack(np.broadcast_arrays(-dx, -dy, np.ones_like(dx)), axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def patch(self, x, y, yaw, n: int, spacing: float) -> np.ndarray:
        """Heights on an n x n body-frame grid centred at (x, y) and turned by yaw.

        Entry [..., i, j] samples the body offset (u, v) = ((i - (n-1)/2) spacing,
        (j - (n-1)/2) spacing), u along the body's x. Batched: x, y, yaw of shape (B,) give
        (B, n, n). Absolute heights (callers subtract a reference if they want one).
        """
        if int(n) < 1:
            raise bad_value("patch.n", n, "must be at least 1", TerrainError)
        if not spacing > 0:
            raise bad_value("patch.spacing", spacing, "must be positive", TerrainError)
        offsets = (np.arange(n) - (n - 1) / 2.0) * spacing
        u, v = np.meshgrid(offsets, offsets, indexing="ij")
        x, y, yaw = (np.asarray(a, dtype=float)[..., None, None] for a in (x, y, yaw))
        c, s = np.cos(yaw), np.sin(yaw)
        return self.height(x + c * u - s * v, y + s * u + c * v)

    def material_at(self, x, y) -> np.ndarray:
        """Material names at (x, y) (nearest cell)."""
        if self.materials is None:
            raise bad_value("heightmap.materials", None, "this map has no material labels", TerrainError)
        ix, iy = self.index(x, y)
        return np.asarray(self.material_names, dtype=object)[self.materials[iy, ix]]

    def crop(self, xmin: float, xmax: float, ymin: float, ymax: float) -> "HeightMap":
        """The sub-map of cells whose centres lie in the given box."""
        xs, ys = self.x_coords, self.y_coords
        cols = np.nonzero((xs >= xmin) & (xs <= xmax))[0]
        rows = np.nonzero((ys >= ymin) & (ys <= ymax))[0]
        if len(cols) < 2 or len(rows) < 2:
            raise bad_value("crop", (xmin, xmax, ymin, ymax), "keeps fewer than 2 x 2 cells", TerrainError)
        sl = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        return HeightMap(self.heights[sl].copy(), self.resolution, (xs[cols[0]], ys[rows[0]]),
                         None if self.materials is None else self.materials[sl].copy(), self.material_names)

    # -- files ------------------------------------------------------------------------------
    def save_npz(self, path: str | Path) -> None:
        np.savez_compressed(path, heights=self.heights, resolution=self.resolution,
                            origin=np.asarray(self.origin),
                            materials=np.zeros((0, 0), np.int64) if self.materials is None else self.materials,
                            material_names=np.asarray(self.material_names, dtype=str))

    @classmethod
    def load_npz(cls, path: str | Path) -> "HeightMap":
        try:
            with np.load(path, allow_pickle=False) as data:
                materials = data["materials"] if "materials" in data and data["materials"].size else None
                names = tuple(str(s) for s in data["material_names"]) if "material_names" in data else ()
                return cls(data["heights"], float(data["resolution"]), tuple(data["origin"]),
                           materials, names)
        except (KeyError, ValueError, OSError) as e:
            raise bad_value("heightmap file", str(path), f"not a qz_drake heightmap .npz ({e})",
                            TerrainError) from None

    def save_png(self, path: str | Path) -> Path:
        """16-bit grayscale PNG plus ``<stem>.yaml`` (image, resolution, origin, min/max height);
        row 0 of the image is the map's largest y (north up), as map servers draw maps."""
        from PIL import Image

        path = Path(path)
        lo, hi = float(self.heights.min()), float(self.heights.max())
        scale = (self.heights - lo) / (hi - lo) if hi > lo else np.zeros_like(self.heights)
        pixels = np.rint(scale * 65535).astype(np.uint16)[::-1]
        Image.fromarray(pixels).save(path)
        meta = {"image": path.name, "resolution": self.resolution, "origin": list(self.origin),
                "min_height": lo, "max_height": hi}
        meta_path = path.with_suffix(".yaml")
        meta_path.write_text(yaml.safe_dump(meta, sort_keys=False))
        return meta_path

    @classmethod
    def from_image(cls, path: str | Path, resolution: float, min_height: float, max_height: float,
                   origin: tuple[float, float] | None = None) -> "HeightMap":
        """Reads an 8-bit or 16-bit grayscale (or RGB/RGBA, first channel) image; pixel values
        map linearly from [0, full scale] to [min_height, max_height]; image row 0 is the
        largest y. The default origin centres the map on (0, 0)."""
        from PIL import Image

        path = Path(path)
        if not path.is_file():
            raise bad_value("heightmap image", str(path), "no such file", TerrainError)
        if not max_height >= min_height:
            raise bad_value("max_height", max_height, f"must be >= min_height {min_height}", TerrainError)
        image = Image.open(path)
        pixels = np.asarray(image)
        if pixels.ndim == 3:
            pixels = pixels[..., 0]
        full = 65535.0 if pixels.dtype == np.uint16 or image.mode.startswith("I") else 255.0
        if pixels.dtype not in (np.uint8, np.uint16) and full == 65535.0:
            full = 65535.0 if pixels.max() > 255 else 255.0
        heights = min_height + (pixels[::-1].astype(float) / full) * (max_height - min_height)
        if origin is None:
            H, W = heights.shape
            origin = (-(W - 1) * resolution / 2.0, -(H - 1) * resolution / 2.0)
        return cls(heights, resolution, origin)

    @classmethod
    def load(cls, path: str | Path) -> "HeightMap":
        """Loads a ``.npz`` or a map-server style ``.yaml`` (with its image)."""
        path = Path(path)
        if path.suffix == ".npz":
            return cls.load_npz(path)
        if path.suffix in (".yaml", ".yml"):
            meta = yaml.safe_load(path.read_text())
            try:
                return cls.from_image(path.parent / meta["image"], float(meta["resolution"]),
                                      float(meta["min_height"]), float(meta["max_height"]),
                                      tuple(meta["origin"]))
            except (KeyError, TypeError) as e:
                raise bad_value("heightmap yaml", str(path), f"missing or bad field {e}", TerrainError) from None
        raise bad_value("heightmap file", str(path), "expected a .npz or .yaml file", TerrainError)
