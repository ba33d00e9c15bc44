"""HeightMap: terrain heights on a regular grid, the way grid_map and map servers store them.

The data type every part of qz_drake shares (DESIGN.md, "Data types"): the capability model
samples body-frame patches from it (paper 001, Sec. II-E: n x n grids around the robot), the
trajectory optimiser queries heights and normals (towr's ``HeightMap::GetHeight``), the station
turns it into Drake contact geometry.

Conventions:

* Cell (ix, iy) has its centre at x = origin[0] + ix * resolution, y = origin[1] + iy * resolution
  and its height in ``heights[iy, ix]`` (row index = y, column index = x). The cell covers
  [x - resolution/2, x + resolution/2) x [y - resolution/2, y + resolution/2); this is what the
  Drake box geometry draws.
* ``height(x, y)`` is the bilinear interpolant of the cell-centre heights, so a step between two
  cells looks like a one-cell ramp to it. Outside the cell centres' rectangle the query is
  clamped to the border: the map's edge continues as a plateau, and every query stays defined
  for planners that peek past the edge. ``gradient`` is the exact derivative of that clamped
  interpolant (zero across a clamped direction).
* Images are drawn north up, as map servers do: image row 0 is the largest y.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import yaml

from qz_drake.errors import TerrainError, bad_value

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Most cells a map may have: a 200 m x 200 m map at 0.05 m. Measured on it, `qz terrain rough`
# peaks at 2.0 GB (about 100 B per cell while generating and drawing) and takes 11 s; a
# user's size_x = 1e6 m (1.6e9 cells) was killed by the kernel at 24 GB after minutes.
MAX_CELLS = 16_000_000
# Pixels whose alpha is below this fraction are "no data" in grid_map's image converter.
_ALPHA_THRESHOLD = 0.5


def _error(field: str, value, why: str) -> TerrainError:
    return bad_value(field, value, why, TerrainError)


def check_cell_count(field: str, value, rows: int, columns: int, resolution: float | None = None) -> None:
    """Refuses a map of ``rows`` x ``columns`` cells beyond MAX_CELLS before it is built,
    naming ``field`` and ``value`` (the parameter that made it so large)."""
    cells = int(rows) * int(columns)
    if cells > MAX_CELLS:
        extent = "" if resolution is None else \
            f"{columns * resolution:.4g} m x {rows * resolution:.4g} m at {resolution:g} m cells: "
        raise _error(field, value, f"{extent}{columns} x {rows} = {cells:.3g} cells, about {cells * 100 / 1e9:.3g} GB "
                                   f"to build; at most {MAX_CELLS:.3g} cells (e.g. 200 m x 200 m at 0.05 m)")


def _finite_float(field: str, value) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise _error(field, value, "expected a number") from None
    if not math.isfinite(number):
        raise _error(field, value, "must be finite")
    return number


@dataclasses.dataclass(eq=False)
class HeightMap:
    """Terrain heights on a regular grid, with optional per-cell ground material labels.

    Compared by identity (``eq=False``): equality of two maps means comparing arrays, which
    callers do with numpy.
    """

    # (H, W) heights [m]; heights[iy, ix] is the height at the centre of cell (ix, iy).
    heights: np.ndarray
    # Cell size. [m]
    resolution: float
    # World (x, y) of the centre of cell (0, 0). [m]
    origin: tuple[float, float] = (0.0, 0.0)
    # (H, W) integer indices into material_names, or None (one material everywhere).
    materials: np.ndarray | None = None
    # Names of the ground materials the labels index (see qz_drake.terrain.materials).
    material_names: tuple[str, ...] = ()

    def __post_init__(self):
        try:
            heights = np.array(self.heights, dtype=np.float64)
        except (TypeError, ValueError):
            raise _error("heightmap.heights", type(self.heights).__name__, "not an array of numbers") from None
        if heights.ndim != 2 or heights.shape[0] < 2 or heights.shape[1] < 2:
            raise _error("heightmap.heights", f"array of shape {heights.shape}",
                         "expected a 2-D array of at least 2 x 2 cells")
        bad = ~np.isfinite(heights)
        if bad.any():
            iy, ix = np.argwhere(bad)[0]
            raise _error(f"heightmap.heights[{iy}, {ix}]", float(heights[iy, ix]), "heights must be finite")
        self.heights = heights
        resolution = _finite_float("heightmap.resolution", self.resolution)
        if resolution <= 0:
            raise _error("heightmap.resolution", self.resolution, "must be positive")
        self.resolution = resolution
        origin = np.asarray(self.origin, dtype=object).reshape(-1)
        if origin.size != 2:
            raise _error("heightmap.origin", self.origin, "expected two numbers (x, y)")
        self.origin = (_finite_float("heightmap.origin", origin[0]), _finite_float("heightmap.origin", origin[1]))
        if isinstance(self.material_names, str):
            self.material_names = (self.material_names,)
        self.material_names = tuple(str(name) for name in self.material_names)
        if self.materials is not None:
            labels = np.asarray(self.materials)
            if labels.shape != heights.shape:
                raise _error("heightmap.materials", f"array of shape {labels.shape}",
                             f"must have the heights' shape {heights.shape}")
            if not np.issubdtype(labels.dtype, np.integer):
                if not (np.issubdtype(labels.dtype, np.floating) and np.all(np.mod(labels, 1) == 0)):
                    raise _error("heightmap.materials", f"array of {labels.dtype}", "labels must be integers")
            labels = labels.astype(np.int64)
            if labels.min() < 0 or labels.max() >= len(self.material_names):
                raise _error("heightmap.materials", f"labels {labels.min()}..{labels.max()}",
                             f"must index material_names {self.material_names}")
            self.materials = labels

    # -- grid ---------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """(H, W): number of cells along y and along x."""
        return self.heights.shape

    @property
    def x_coords(self) -> np.ndarray:
        """(W,) x of the cell centres. [m]"""
        return self.origin[0] + self.resolution * np.arange(self.heights.shape[1])

    @property
    def y_coords(self) -> np.ndarray:
        """(H,) y of the cell centres. [m]"""
        return self.origin[1] + self.resolution * np.arange(self.heights.shape[0])

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the cell centres. [m]"""
        H, W = self.heights.shape
        return (self.origin[0], self.origin[0] + (W - 1) * self.resolution,
                self.origin[1], self.origin[1] + (H - 1) * self.resolution)

    def contains(self, x, y) -> np.ndarray:
        """Whether (x, y) lies within the cell centres' rectangle, where no clamping happens."""
        xmin, xmax, ymin, ymax = self.bounds
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)

    def index(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """(ix, iy) of the cell containing (x, y), clamped to the map (nearest cell centre)."""
        H, W = self.heights.shape
        u = np.floor((np.asarray(x, dtype=float) - self.origin[0]) / self.resolution + 0.5)
        v = np.floor((np.asarray(y, dtype=float) - self.origin[1]) / self.resolution + 0.5)
        u, v = np.nan_to_num(u, nan=0.0), np.nan_to_num(v, nan=0.0)
        return np.clip(u, 0, W - 1).astype(np.int64), np.clip(v, 0, H - 1).astype(np.int64)

    # -- interpolation ------------------------------------------------------------------------
    def _corners(self, x, y):
        """Corner heights of the interpolation quad of each query, the fractions inside it, and
        masks for queries inside the map (per direction) and for NaN queries."""
        H, W = self.heights.shape
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        u = (x - self.origin[0]) / self.resolution
        v = (y - self.origin[1]) / self.resolution
        nan = np.isnan(u) | np.isnan(v)
        uc = np.clip(np.where(nan, 0.0, u), 0.0, W - 1.0)
        vc = np.clip(np.where(nan, 0.0, v), 0.0, H - 1.0)
        # The quad's lower-left cell; on the last centre use the quad to its left (below).
        i0 = np.minimum(uc.astype(np.int64), W - 2)
        j0 = np.minimum(vc.astype(np.int64), H - 2)
        h = self.heights
        corners = (h[j0, i0], h[j0, i0 + 1], h[j0 + 1, i0], h[j0 + 1, i0 + 1])
        inside_x = (u >= 0.0) & (u <= W - 1.0)
        inside_y = (v >= 0.0) & (v <= H - 1.0)
        return corners, uc - i0, vc - j0, inside_x, inside_y, nan

    def height(self, x, y) -> np.ndarray:
        """Bilinear height at world (x, y), clamped to the border outside the map. [m]

        Vectorised: x and y broadcast against each other. NaN queries give NaN.
        """
        (h00, h10, h01, h11), fx, fy, _, _, nan = self._corners(x, y)
        z = (h00 * (1 - fx) + h10 * fx) * (1 - fy) + (h01 * (1 - fx) + h11 * fx) * fy
        return np.where(nan, np.nan, z) if nan.any() else z

    def gradient(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """(dh/dx, dh/dy): the exact derivative of ``height``'s interpolant.

        On a line between two quads the quad above / to the right is used (the last quad at the
        map's far edge); across a clamped direction outside the map the derivative is zero.
        """
        (h00, h10, h01, h11), fx, fy, inside_x, inside_y, nan = self._corners(x, y)
        dx = ((h10 - h00) * (1 - fy) + (h11 - h01) * fy) / self.resolution
        dy = ((h01 - h00) * (1 - fx) + (h11 - h10) * fx) / self.resolution
        dx = np.where(nan, np.nan, np.where(inside_x, dx, 0.0))
        dy = np.where(nan, np.nan, np.where(inside_y, dy, 0.0))
        return dx, dy

    def normal(self, x, y) -> np.ndarray:
        """Unit surface normals (..., 3) = normalise(-dh/dx, -dh/dy, 1)."""
        dx, dy = self.gradient(x, y)
        n = np.stack([-dx, -dy, np.ones_like(dx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def patch(self, x, y, yaw, n: int, spacing: float) -> np.ndarray:
        """Heights on an n x n body-frame grid centred on (x, y) and turned by yaw. [m]

        Entry [..., i, j] samples the body offset (u, v) = ((i - (n-1)/2) * spacing,
        (j - (n-1)/2) * spacing), u along the body's x, mapped to the world by the rotation yaw.
        x, y and yaw broadcast: arrays of shape (B,) give (B, n, n). The heights are absolute;
        callers subtract a reference height if they want relative ones.
        """
        if isinstance(n, bool) or not float(n).is_integer() or n < 1:
            raise _error("patch.n", n, "must be a positive whole number")
        spacing_value = _finite_float("patch.spacing", spacing)
        if spacing_value <= 0:
            raise _error("patch.spacing", spacing, "must be positive")
        offsets = (np.arange(int(n)) - (int(n) - 1) / 2.0) * spacing_value
        u, v = offsets[:, None], offsets[None, :]
        x, y, yaw = (np.asarray(a, dtype=float)[..., None, None] for a in (x, y, yaw))
        c, s = np.cos(yaw), np.sin(yaw)
        return self.height(x + c * u - s * v, y + s * u + c * v)

    def material_at(self, x, y) -> np.ndarray:
        """Material names at (x, y) (nearest cell); a str for scalar queries."""
        if self.materials is None:
            raise _error("heightmap.materials", None, "this map has no material labels")
        ix, iy = self.index(x, y)
        return np.asarray(self.material_names, dtype=object)[self.materials[iy, ix]]

    def crop(self, xmin: float, xmax: float, ymin: float, ymax: float) -> HeightMap:
        """The sub-map of the cells whose centres lie in [xmin, xmax] x [ymin, ymax]."""
        tolerance = 1e-9 * self.resolution
        xs, ys = self.x_coords, self.y_coords
        cols = np.nonzero((xs >= xmin - tolerance) & (xs <= xmax + tolerance))[0]
        rows = np.nonzero((ys >= ymin - tolerance) & (ys <= ymax + tolerance))[0]
        if len(cols) < 2 or len(rows) < 2:
            raise _error("heightmap.crop", [xmin, xmax, ymin, ymax],
                         f"keeps fewer than 2 x 2 cells of the map (cell centres span {self.bounds})")
        window = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        return HeightMap(self.heights[window].copy(), self.resolution, (float(xs[cols[0]]), float(ys[rows[0]])),
                         None if self.materials is None else self.materials[window].copy(),
                         self.material_names)

    # -- files --------------------------------------------------------------------------------
    def save_npz(self, path: str | Path) -> Path:
        """Writes every field exactly (compressed .npz, loadable without pickle); returns the path."""
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        np.savez_compressed(
            path, heights=self.heights, resolution=np.float64(self.resolution),
            origin=np.asarray(self.origin, dtype=np.float64),
            materials=np.zeros((0, 0), np.int64) if self.materials is None else self.materials,
            material_names=np.asarray(self.material_names, dtype=np.str_))
        return path

    @classmethod
    def load_npz(cls, path: str | Path) -> HeightMap:
        path = Path(path)
        if not path.is_file():
            raise _error("heightmap.file", str(path), "no such file")
        if not zipfile.is_zipfile(path):
            # numpy reads a file that is no zip archive as a pickle and says to trust it.
            raise _error("heightmap.file", str(path), "not a zip archive, so not a .npz heightmap (HeightMap.save_npz, "
                                                      "qz terrain --save)")
        try:
            with np.load(path, allow_pickle=False) as data:
                materials = data["materials"] if "materials" in data and data["materials"].size else None
                names = tuple(str(s) for s in data["material_names"]) if "material_names" in data else ()
                return cls(data["heights"], float(data["resolution"]), tuple(data["origin"]), materials, names)
        except (KeyError, ValueError, OSError, EOFError, zlib.error, zipfile.BadZipFile) as e:
            raise _error("heightmap.file", str(path), f"not a qz_drake heightmap .npz ({e})") from None

    def save_png(self, path: str | Path) -> Path:
        """Writes a 16-bit grayscale PNG and, next to it, ``<stem>.yaml`` as a map server would:
        image, resolution, origin, min_height, max_height. Returns the YAML's path.

        The pixel value p in [0, 65535] stands for min_height + p / 65535 * (max_height -
        min_height), so heights come back within (max - min) / 65535. Row 0 is the largest y.
        ``origin`` is the centre of the bottom-left pixel (map_server uses its corner). Material
        labels, if any, go to ``<stem>_materials.png`` (8-bit label indices) with their names
        in the YAML.
        """
        from PIL import Image

        path = Path(path)
        low, high = float(self.heights.min()), float(self.heights.max())
        scaled = (self.heights - low) / (high - low) if high > low else np.zeros_like(self.heights)
        pixels = np.rint(scaled * 65535.0).astype(np.uint16)[::-1]
        Image.fromarray(np.ascontiguousarray(pixels)).save(path, format="PNG")
        meta = {"image": path.name, "resolution": self.resolution, "origin": list(self.origin),
                "min_height": low, "max_height": high}
        if self.materials is not None:
            if len(self.material_names) > 256:
                raise _error("heightmap.material_names", len(self.material_names),
                             "at most 256 materials fit an 8-bit label image")
            label_path = path.with_name(f"{path.stem}_materials.png")
            labels = np.ascontiguousarray(self.materials.astype(np.uint8)[::-1])
            Image.fromarray(labels).save(label_path, format="PNG")
            meta["materials_image"] = label_path.name
            meta["material_names"] = list(self.material_names)
        meta_path = path.with_suffix(".yaml")
        meta_path.write_text(yaml.safe_dump(meta, sort_keys=False))
        return meta_path

    @classmethod
    def from_image(cls, path: str | Path, resolution: float, min_height: float, max_height: float,
                   origin: tuple[float, float] | None = None) -> HeightMap:
        """Reads a heightmap picture, as grid_map's image converter does.

        8-bit or 16-bit grayscale, or RGB(A) whose first channel holds the height. Pixel values
        map linearly from [0, full scale] (255 or 65535) to [min_height, max_height] [m].
        Pixels with alpha below one half (grid_map: no data) get min_height. Image row 0 is the
        top of the picture = the largest y (north up). The default origin puts the map's centre
        at (0, 0).
        """
        path = Path(path)
        if not path.is_file():
            raise _error("heightmap.image", str(path), "no such file")
        low = _finite_float("heightmap.min_height", min_height)
        high = _finite_float("heightmap.max_height", max_height)
        if high < low:
            raise _error("heightmap.max_height", max_height, f"must be >= min_height {min_height}")
        values, full_scale, opaque = _read_height_image(path)
        rows, columns = values.shape
        if rows < 2 or columns < 2:
            res = _finite_float("heightmap.resolution", resolution)
            raise _error("heightmap.image", str(path),
                         f"{columns} x {rows} pixels; a heightmap needs at least 2 x 2, and a robot as many as "
                         f"span its feet ({1 / res:.3g} pixels per metre at resolution {res:g} m)")
        heights = low + values.astype(np.float64) / full_scale * (high - low)
        if opaque is not None:
            heights = np.where(opaque, heights, low)
        heights = heights[::-1]
        if origin is None:
            res = _finite_float("heightmap.resolution", resolution)
            H, W = heights.shape
            origin = (-(W - 1) * res / 2.0, -(H - 1) * res / 2.0)
        return cls(heights, resolution, origin)

    # Picture files ``load`` reads with a scale given by the caller (grid_map's image converter).
    IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

    @classmethod
    def load(cls, path: str | Path, resolution: float | None = None, min_height: float | None = None,
             max_height: float | None = None) -> HeightMap:
        """Loads a ``.npz`` (save_npz), a map-server style ``.yaml`` with its image (save_png), or
        a picture (``IMAGE_SUFFIXES``) with its scale: ``resolution`` [m] and ``max_height`` [m]
        are then required, ``min_height`` defaults to 0 (see from_image; centred on the origin)."""
        path = Path(path)
        if path.suffix.lower() in cls.IMAGE_SUFFIXES:
            for name, value in (("resolution", resolution), ("max_height", max_height)):
                if value is None:
                    raise _error(f"heightmap.{name}", None,
                                 f"required to read the picture {path.name} (e.g. resolution 0.05, "
                                 f"min_height 0, max_height 0.4)")
            return cls.from_image(path, resolution, 0.0 if min_height is None else min_height, max_height)
        if path.suffix == ".npz":
            return cls.load_npz(path)
        if path.suffix not in (".yaml", ".yml"):
            raise _error("heightmap.file", str(path),
                         f"expected a .npz, a map-server .yaml or a picture ({', '.join(cls.IMAGE_SUFFIXES)})")
        if not path.is_file():
            raise _error("heightmap.file", str(path), "no such file")
        try:
            meta = yaml.safe_load(path.read_text())
        except yaml.YAMLError as e:
            raise _error("heightmap.file", str(path), f"not valid YAML ({e})") from None
        if not isinstance(meta, dict):
            raise _error("heightmap.file", str(path), "expected a mapping with image, resolution, origin, ...")
        for key in ("image", "resolution", "min_height", "max_height"):
            if key not in meta:
                raise _error(f"heightmap.{key}", None, f"missing from {path}")
        origin = meta.get("origin")
        if origin is not None:
            origin = np.asarray(origin, dtype=object).reshape(-1)[:2]  # map_server adds a yaw
        heightmap = cls.from_image(path.parent / str(meta["image"]), meta["resolution"], meta["min_height"],
                                   meta["max_height"], None if origin is None else tuple(origin))
        if "materials_image" in meta:
            labels, _, _ = _read_height_image(path.parent / str(meta["materials_image"]))
            heightmap = cls(heightmap.heights, heightmap.resolution, heightmap.origin,
                            labels[::-1].astype(np.int64), tuple(meta.get("material_names", ())))
        return heightmap


def _read_height_image(path: Path) -> tuple[np.ndarray, float, np.ndarray | None]:
    """(first channel as integers, full-scale value, opaque mask or None) of an image."""
    from PIL import Image, UnidentifiedImageError

    decoded = _read_png_16bit_colour(path)
    if decoded is not None:
        return decoded
    try:
        image = Image.open(path)
        # The header alone gives the size: a picture too large for memory is refused unread.
        check_cell_count("heightmap.image", str(path), image.size[1], image.size[0])
        image.load()
    except (UnidentifiedImageError, OSError) as e:
        raise _error("heightmap.image", str(path), f"not a readable image ({e})") from None
    if image.mode in ("P", "1"):
        image = image.convert("LA" if "transparency" in image.info else "L")
    if image.mode in ("L", "LA", "RGB", "RGBA"):
        pixels = np.asarray(image)
        if pixels.ndim == 2:
            return pixels, 255.0, None
        opaque = pixels[..., -1] >= _ALPHA_THRESHOLD * 255 if image.mode in ("LA", "RGBA") else None
        return pixels[..., 0], 255.0, opaque
    if image.mode.startswith("I;16") or image.mode == "I":
        # PNG stores 16-bit grayscale; PIL may widen it to 32-bit mode "I".
        return np.asarray(image).astype(np.int64), 65535.0, None
    raise _error("heightmap.image", str(path), f"unsupported image mode {image.mode!r}")


def _read_png_16bit_colour(path: Path) -> tuple[np.ndarray, float, np.ndarray | None] | None:
    """Decodes a 16-bit RGB, RGBA or gray+alpha PNG, which PIL cuts down to 8 bits.

    Returns (first channel, 65535, opaque mask or None), or None for any other file.
    """
    data = path.read_bytes()
    if not data.startswith(_PNG_SIGNATURE):
        return None
    header, chunks, position = None, [], len(_PNG_SIGNATURE)
    while position + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[position:position + 8])
        body = data[position + 8:position + 8 + length]
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body[:13])
        elif kind == b"IDAT":
            chunks.append(body)
        elif kind == b"IEND":
            break
        position += 12 + length
    if header is None:
        return None
    width, height, bit_depth, colour_type, _, _, interlace = header
    check_cell_count("heightmap.image", str(path), height, width)
    channels = {2: 3, 4: 2, 6: 4}.get(colour_type)
    if bit_depth != 16 or channels is None:
        return None
    if interlace:
        raise _error("heightmap.image", str(path), "interlaced 16-bit colour PNGs are not supported")
    pixel_bytes = 2 * channels
    stride = width * pixel_bytes
    try:
        raw = np.frombuffer(zlib.decompress(b"".join(chunks)), np.uint8)
        rows = raw[:height * (stride + 1)].reshape(height, stride + 1)
    except (zlib.error, ValueError) as e:
        raise _error("heightmap.image", str(path), f"corrupt PNG data ({e})") from None
    image = np.empty((height, stride), np.uint8)
    previous = np.zeros(stride, np.uint8)
    for r in range(height):
        kind, line = int(rows[r, 0]), rows[r, 1:]
        if kind == 0:
            current = line.copy()
        elif kind == 1:  # Sub: a running sum along each byte position of the pixel
            current = (np.cumsum(line.reshape(width, pixel_bytes).astype(np.int64), axis=0) % 256
                       ).astype(np.uint8).reshape(-1)
        elif kind == 2:  # Up
            current = line + previous
        elif kind in (3, 4):  # Average, Paeth: sequential within a row
            current = _unfilter_row(kind, line, previous, pixel_bytes)
        else:
            raise _error("heightmap.image", str(path), f"bad PNG filter type {kind} in row {r}")
        image[r] = current
        previous = current
    samples = image.reshape(height, width, channels, 2).astype(np.uint16)
    values = (samples[..., 0] << 8) | samples[..., 1]
    opaque = values[..., -1] >= _ALPHA_THRESHOLD * 65535 if colour_type in (4, 6) else None
    return values[..., 0], 65535.0, opaque


def _unfilter_row(kind: int, line: np.ndarray, previous: np.ndarray, pixel_bytes: int) -> np.ndarray:
    """Undoes the PNG Average (3) or Paeth (4) filter of one row."""
    filtered, above = line.tolist(), previous.tolist()
    out = [0] * len(filtered)
    for i, value in enumerate(filtered):
        left = out[i - pixel_bytes] if i >= pixel_bytes else 0
        up = above[i]
        if kind == 3:
            predictor = (left + up) >> 1
        else:
            upper_left = above[i - pixel_bytes] if i >= pixel_bytes else 0
            p = left + up - upper_left
            pa, pb, pc = abs(p - left), abs(p - up), abs(p - upper_left)
            predictor = left if pa <= pb and pa <= pc else up if pb <= pc else upper_left
        out[i] = (value + predictor) & 0xFF
    return np.asarray(out, dtype=np.uint8)
