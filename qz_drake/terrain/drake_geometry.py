"""A HeightMap as contact geometry of a Drake MultibodyPlant.

Two representations, both measured on drake 1.51 (issue 2):

* **boxes**: cells of equal height and material are merged into maximal axis-aligned
  rectangles, each registered as a box with *point* contact. Exact for box-like terrains
  (flat, stairs, steps, gaps) and fast (about 3x real time standing). The number of boxes grows
  with the number of distinct height patches, so it only suits piecewise-constant maps.
* **mesh**: the top surface of the map as a triangle mesh (one ``.obj`` per material),
  registered as *rigid hydroelastic*; the robot's collision geometry must then be compliant
  hydroelastic (see :func:`make_robot_proximity_properties`). A ``Mesh`` under point contact
  would be replaced by its convex hull (the robot floats), so the mesh is never used with
  point contact. What is drawn of it is the same surface with every planar rectangle of cells
  drawn whole (:func:`drawn_surface_objs`): the 20 m long_range world is drawn with a tenth of
  the contact mesh's triangles (its recording was 26 MB, 12 MB of them the terrain). The
  meshes are held in memory (Drake's ``InMemoryMesh``), in files only where ``mesh_dir`` asks.

``"auto"`` chooses boxes when the map decomposes into at most ``max_boxes`` rectangles.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
from pydrake.common import MemoryFile
from pydrake.geometry import (AddCompliantHydroelasticProperties, AddContactMaterial,
                              AddRigidHydroelasticProperties, Box, InMemoryMesh, Mesh, ProximityProperties)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant

from qz_drake.errors import TerrainError, bad_value
from qz_drake.terrain.materials import GroundMaterial, get_material

CONTACT_KINDS = ("auto", "boxes", "mesh")
# Registering boxes costs quadratic time in their number (5k boxes: 41 s measured); past this
# many, "boxes" is refused with an error rather than taking minutes.
MAX_FORCED_BOXES = 1500
# Boxes reach this far below the lowest cell so feet never fall under the terrain. [m]
_BOX_FLOOR_DEPTH = 0.5
# Visual colours (issue 39: a uniform grey terrain hid the stairs). A map of one material is
# coloured by height, from a muted green at its lowest to a pale sand at its highest, so that the
# orange trunk and blue legs stand out from any of it; a map with material labels keeps one
# colour per material (the mixed floor of the classification scenes shows which is which).
TERRAIN_LOW_RGB = np.array([0.4, 0.6, 0.45])
TERRAIN_HIGH_RGB = np.array([0.92, 0.87, 0.72])
_MATERIAL_RGB = {
    "concrete": np.array([0.7, 0.7, 0.68]),
    "wood": np.array([0.72, 0.52, 0.3]),
    "foam": np.array([0.4, 0.6, 0.85]),
}
# Every other HEIGHT_BAND of height is drawn BAND_SHADE darker: each step of a stair (rises of
# 0.08-0.15 m) and each box then differs from its neighbour even where the height ramp alone
# changes by a few per cent (a 0.1 m step on the 20 m long_range world, 1.5 m high). [m]
HEIGHT_BAND = 0.1
BAND_SHADE = 0.85
# A mesh terrain is drawn as one visual mesh per band (the collision mesh stays whole); past this
# many bands they are widened, so a map of any height range costs a bounded number of objects.
MAX_VISUAL_BANDS = 48
# Cells whose corners lie this close to one plane are drawn merged (far below what a screen
# shows; the generators' planar features are planar to rounding error). [m]
VISUAL_PLANAR_TOLERANCE = 1e-6


@dataclasses.dataclass(frozen=True)
class TerrainBox:
    """An axis-aligned box of terrain: cell ranges [ix0, ix1) x [iy0, iy1) at one height."""

    ix0: int
    ix1: int
    iy0: int
    iy1: int
    height: float
    material: int


def decompose_into_boxes(heights: np.ndarray, materials: np.ndarray | None = None,
                         max_boxes: int | None = None) -> list[TerrainBox] | None:
    """Greedy maximal-rectangle cover of cells with equal (height, material).

    Scans cells row by row; from each uncovered cell grows a rectangle first along x, then
    along y while whole rows match. Returns None once more than ``max_boxes`` are needed.
    """
    H, W = heights.shape
    mats = np.zeros((H, W), dtype=np.int64) if materials is None else np.asarray(materials)
    covered = np.zeros((H, W), dtype=bool)
    boxes: list[TerrainBox] = []
    for iy in range(H):
        ix = 0
        while ix < W:
            if covered[iy, ix]:
                ix += 1
                continue
            h, m = heights[iy, ix], mats[iy, ix]
            row_match = (heights[iy, ix:] == h) & (mats[iy, ix:] == m) & ~covered[iy, ix:]
            run = int(np.argmin(row_match)) if not row_match.all() else W - ix
            iy1 = iy + 1
            while iy1 < H:
                seg = slice(ix, ix + run)
                if np.all(heights[iy1, seg] == h) and np.all(mats[iy1, seg] == m) and not covered[iy1, seg].any():
                    iy1 += 1
                else:
                    break
            covered[iy:iy1, ix:ix + run] = True
            boxes.append(TerrainBox(ix, ix + run, iy, iy1, float(h), int(m)))
            if max_boxes is not None and len(boxes) > max_boxes:
                return None
            ix += run
    return boxes


def terrain_rgba(height: float, low: float, high: float, *, band: float = HEIGHT_BAND,
                 material: str | None = None) -> np.ndarray:
    """Visual colour of terrain at ``height`` [m] on a map whose heights span [low, high]:
    the height ramp (or the colour of ``material``, for maps with material labels), darkened
    by BAND_SHADE on every other ``band`` of height."""
    if material is not None:
        rgb = _MATERIAL_RGB.get(material, TERRAIN_HIGH_RGB)
    else:
        fraction = (height - low) / (high - low) if high > low else 0.0
        rgb = TERRAIN_LOW_RGB + float(np.clip(fraction, 0.0, 1.0)) * (TERRAIN_HIGH_RGB - TERRAIN_LOW_RGB)
    # Rounded first: 0.3 / 0.1 is 2.9999999999999996, and a 0.3 m box is in band 3.
    index = math.floor(round(height / band, 6))
    shade = 1.0 if index % 2 == 0 else BAND_SHADE
    return np.append(rgb * shade, 1.0)


def _visual_band(heights: np.ndarray) -> float:
    """The height band of the map's colours: HEIGHT_BAND, or wider where the map would need more
    than MAX_VISUAL_BANDS of them. [m]"""
    span = float(heights.max() - heights.min())
    return max(HEIGHT_BAND, span / (MAX_VISUAL_BANDS - 1))


def point_contact_properties(material: GroundMaterial) -> ProximityProperties:
    props = ProximityProperties()
    AddContactMaterial(dissipation=material.hunt_crossley_dissipation,
                       point_stiffness=material.stiffness,
                       friction=CoulombFriction(material.static_friction, material.dynamic_friction),
                       properties=props)
    return props


def planar_rectangles(heights: np.ndarray, cell_mask: np.ndarray | None = None,
                      tolerance: float = VISUAL_PLANAR_TOLERANCE) -> np.ndarray:
    """Rectangles of quads (rows [iy0, iy1) x columns [ix0, ix1) of the (H-1, W-1) quads between
    cell centres) that cover the quads of ``cell_mask`` (all: None), as an (n, 4) int array
    ``(iy0, iy1, ix0, ix1)``; each rectangle's corners, and every cell centre inside it, lie on
    one plane within ``tolerance`` [m]. A quad that is not planar is a rectangle of its own.

    Quads are planar and share a plane when their height differences along x and along y are
    the same (neighbours share an edge, so the same slopes mean the same plane). Runs of such
    quads along each row become rectangles that grow down while the next row has the same run.
    Where a rectangle meets smaller ones, their vertices on its edge lie on its plane, so the
    surface has no cracks."""
    h = np.asarray(heights, dtype=float)
    rows, cols = h.shape[0] - 1, h.shape[1] - 1
    slope_x = h[:-1, 1:] - h[:-1, :-1]
    slope_y = h[1:, :-1] - h[:-1, :-1]
    planar = np.abs(h[1:, 1:] - h[:-1, 1:] - slope_y) <= tolerance
    mask = np.ones((rows, cols), dtype=bool) if cell_mask is None else np.asarray(cell_mask, dtype=bool)
    merged = planar & mask
    # A quad's plane, as integers: its slopes in units of the tolerance (-1, -1 where not merged).
    plane_x = np.where(merged, np.round(slope_x / tolerance), -1).astype(np.int64)
    plane_y = np.where(merged, np.round(slope_y / tolerance), -1).astype(np.int64)
    # Where a run along a row ends: the plane changes or the merged quads do.
    breaks = (np.diff(plane_x, axis=1) != 0) | (np.diff(plane_y, axis=1) != 0) | (np.diff(merged, axis=1) != 0)
    rectangles = []
    growing: dict[tuple[int, int, int, int], int] = {}  # (ix0, ix1, plane) -> iy0
    for iy in range(rows):
        edges = np.flatnonzero(breaks[iy]) + 1
        starts, ends = np.concatenate([[0], edges]), np.concatenate([edges, [cols]])
        runs = {}
        for ix0, ix1 in zip(starts.tolist(), ends.tolist()):
            if merged[iy, ix0]:
                run = (ix0, ix1, int(plane_x[iy, ix0]), int(plane_y[iy, ix0]))
                runs[run] = growing.pop(run, iy)
        rectangles += [(iy0, iy, ix0, ix1) for (ix0, ix1, _, _), iy0 in growing.items()]
        growing = runs
    rectangles += [(iy0, rows, ix0, ix1) for (ix0, ix1, _, _), iy0 in growing.items()]
    single_y, single_x = np.nonzero(mask & ~planar)
    singles = np.stack([single_y, single_y + 1, single_x, single_x + 1], axis=1)
    return np.concatenate([np.asarray(rectangles, dtype=np.int64).reshape(-1, 4), singles])


def _grid_vertices(heightmap) -> np.ndarray:
    """The map's cell centres as vertices (H*W, 3), row by row (vertex ``iy * W + ix``)."""
    h = np.asarray(heightmap.heights, dtype=float)
    H, W = h.shape
    xs = heightmap.origin[0] + heightmap.resolution * np.arange(W)
    ys = heightmap.origin[1] + heightmap.resolution * np.arange(H)
    X, Y = np.meshgrid(xs, ys)
    return np.stack([X.ravel(), Y.ravel(), h.ravel()], axis=1)


def _rectangle_faces(W: int, iy0, iy1, ix0, ix1) -> np.ndarray:
    """Two triangles per rectangle of quads (corner vertices of a map W cells wide), normals up:
    every rectangle's first triangle, then every second one."""
    a, b = iy0 * W + ix0, iy0 * W + ix1
    c, d = iy1 * W + ix0, iy1 * W + ix1
    return np.concatenate([np.stack([a, b, d], axis=1), np.stack([a, d, c], axis=1)])


def _obj_text(vertices: np.ndarray, faces: np.ndarray) -> str:
    """Wavefront OBJ text of triangles (rows of indices into ``vertices``) with only the vertices
    they use, so that each file is self-contained."""
    used, triangles = np.unique(faces, return_inverse=True)
    # One %-format over all numbers: a 400 x 400 map's text in 0.63 s instead of 1.56 s with a
    # loop over lines (the mesh terrain is written twice: whole for contact, in height bands to
    # be drawn).
    kept, triangles = vertices[used], triangles.reshape(faces.shape) + 1  # OBJ indices are 1-based
    return ("# qz_drake heightmap surface\n" + "v %.6f %.6f %.6f\n" * len(kept) % tuple(kept.ravel())
            + "f %d %d %d\n" * len(triangles) % tuple(triangles.ravel().tolist()))


def heightmap_surface_obj(heightmap, cell_mask: np.ndarray | None = None) -> str:
    """Wavefront OBJ text of the map's top surface (two triangles per pair of neighbouring
    cell centres, normals up). ``cell_mask`` (H-1, W-1) keeps only some quads."""
    H, W = np.shape(heightmap.heights)
    iy0, ix0 = np.nonzero(np.ones((H - 1, W - 1), dtype=bool) if cell_mask is None else cell_mask)
    return _obj_text(_grid_vertices(heightmap), _rectangle_faces(W, iy0, iy0 + 1, ix0, ix0 + 1))


def drawn_surface_objs(heightmap, cell_masks) -> list[str]:
    """Wavefront OBJ texts of the map's top surface as it is drawn, one per mask of the (H-1,
    W-1) quads (disjoint: a height band of a material each): the surface of
    heightmap_surface_obj with every planar rectangle of quads (planar_rectangles) drawn whole.

    Where a corner of another rectangle, of any of the masks, lies on a rectangle's edge, the
    rectangle is drawn as a fan from its centre through every such corner: the meshes then meet
    vertex to vertex, without the one-pixel cracks that show the sky along an edge where a
    vertex of one mesh lies on an edge of another."""
    h = np.asarray(heightmap.heights, dtype=float)
    H, W = h.shape
    grid = _grid_vertices(heightmap)
    rectangles = [planar_rectangles(h, mask) for mask in cell_masks]
    corner = np.zeros((H, W), dtype=bool)
    for iy0, iy1, ix0, ix1 in (r.T for r in rectangles):
        corner[iy0, ix0] = corner[iy0, ix1] = corner[iy1, ix0] = corner[iy1, ix1] = True
    along_x, along_y = np.cumsum(corner, axis=1), np.cumsum(corner, axis=0)  # corners up to x, y
    texts = []
    for r in rectangles:
        iy0, iy1, ix0, ix1 = r.T
        # Corners strictly inside the rectangle's four edges.
        inside = (along_x[iy0, ix1 - 1] - along_x[iy0, ix0] + along_x[iy1, ix1 - 1] - along_x[iy1, ix0]
                  + along_y[iy1 - 1, ix0] - along_y[iy0, ix0] + along_y[iy1 - 1, ix1] - along_y[iy0, ix1])
        faces = [_rectangle_faces(W, *r[inside == 0].T)]
        centres = []
        for iy0, iy1, ix0, ix1 in r[inside > 0]:
            # The boundary counter-clockwise through every corner on it, each side from its
            # first corner up to the next side's.
            bottom, right = np.arange(ix0, ix1), np.arange(iy0, iy1)
            top, left = np.arange(ix1, ix0, -1), np.arange(iy1, iy0, -1)
            ring = np.concatenate([(iy0 * W + bottom)[corner[iy0, bottom]], (right * W + ix1)[corner[right, ix1]],
                                   (iy1 * W + top)[corner[iy1, top]], (left * W + ix0)[corner[left, ix0]]])
            centre = len(grid) + len(centres)
            centres.append(grid[[iy0 * W + ix0, iy0 * W + ix1, iy1 * W + ix0, iy1 * W + ix1]].mean(axis=0))
            faces.append(np.column_stack([np.full(len(ring), centre), ring, np.roll(ring, -1)]))
        vertices = np.vstack([grid, *centres]) if centres else grid
        texts.append(_obj_text(vertices, np.concatenate(faces)))
    return texts


def _mesh(obj_text: str, name: str, directory: Path | None) -> Mesh:
    """A Drake Mesh of OBJ text: written to ``directory``/``name`` where one is given, else in
    memory."""
    if directory is None:
        return Mesh(InMemoryMesh(mesh_file=MemoryFile(obj_text, ".obj", name)))
    path = directory / name
    path.write_text(obj_text)
    return Mesh(str(path))


def _material_names(heightmap, default_material: str) -> tuple[str, ...]:
    names = tuple(getattr(heightmap, "material_names", ()) or ())
    if getattr(heightmap, "materials", None) is None or not names:
        return (default_material,)
    return names


def add_heightmap_to_plant(plant: MultibodyPlant, heightmap, *, contact: str = "auto",
                           default_material: str = "concrete", max_boxes: int = 400,
                           mesh_dir: str | Path | None = None) -> str:
    """Registers the map as world collision and visual geometry; returns "boxes" or "mesh".

    With "mesh" the robot's geometry must be compliant hydroelastic and the plant's contact
    model hydroelastic-with-fallback (the station does both); its meshes are held in memory, or
    written as ``.obj`` files to ``mesh_dir`` where it is given.
    """
    if contact not in CONTACT_KINDS:
        raise bad_value("terrain.contact", contact, f"expected one of {', '.join(CONTACT_KINDS)}",
                        TerrainError)
    names = _material_names(heightmap, default_material)
    materials = [get_material(n) for n in names]
    h = np.asarray(heightmap.heights, dtype=float)
    labels = getattr(heightmap, "materials", None) if len(names) > 1 or getattr(
        heightmap, "materials", None) is not None else None
    boxes = None
    if contact in ("auto", "boxes"):
        boxes = decompose_into_boxes(h, labels, MAX_FORCED_BOXES if contact == "boxes" else max_boxes)
    world = plant.world_body()
    res = heightmap.resolution
    low, high, band = float(h.min()), float(h.max()), _visual_band(h)
    by_material = labels is not None  # coloured by material where the map says which is which
    if boxes is not None:
        floor = float(h.min()) - _BOX_FLOOR_DEPTH
        for k, box in enumerate(boxes):
            size_x = (box.ix1 - box.ix0) * res
            size_y = (box.iy1 - box.iy0) * res
            size_z = box.height - floor
            # Cell ix covers [x_ix - res/2, x_ix + res/2).
            cx = heightmap.origin[0] + (box.ix0 - 0.5) * res + size_x / 2
            cy = heightmap.origin[1] + (box.iy0 - 0.5) * res + size_y / 2
            X_WB = RigidTransform([cx, cy, floor + size_z / 2])
            shape = Box(size_x, size_y, size_z)
            material = materials[box.material]
            plant.RegisterCollisionGeometry(world, X_WB, shape, f"terrain_box_{k}",
                                            point_contact_properties(material))
            plant.RegisterVisualGeometry(world, X_WB, shape, f"terrain_box_{k}",
                                         terrain_rgba(box.height, low, high, band=band,
                                                      material=material.name if by_material else None))
        return "boxes"
    if contact == "boxes":
        raise bad_value("terrain.contact", contact,
                        f"this map needs more than {MAX_FORCED_BOXES} boxes; use 'mesh' or 'auto'",
                        TerrainError)
    directory = None if mesh_dir is None else Path(mesh_dir)
    if directory is not None:
        directory.mkdir(parents=True, exist_ok=True)
    # A quad takes the material of its lower-left cell.
    quad_material = (np.zeros(h.shape, dtype=np.int64) if labels is None else np.asarray(labels))[:-1, :-1]
    quad_mean = (h[:-1, :-1] + h[:-1, 1:] + h[1:, :-1] + h[1:, 1:]) / 4.0
    quad_band = np.floor(np.round(quad_mean / band, 6)).astype(np.int64)
    # Drawn in height bands, one mesh each: a mesh takes one colour in meshcat. A quad's band is
    # that of its mean height.
    bands = [(m, index) for m in range(len(materials)) for index in np.unique(quad_band[quad_material == m])]
    drawn = dict(zip(bands, drawn_surface_objs(heightmap, [(quad_material == m) & (quad_band == index)
                                                           for m, index in bands])))
    for m, material in enumerate(materials):
        mask = quad_material == m
        if not mask.any():
            continue
        props = point_contact_properties(material)
        # Rigid terrain: the foot's compliance carries the material's stiffness (see
        # make_robot_proximity_properties); resolution_hint is unused for rigid meshes.
        AddRigidHydroelasticProperties(properties=props)
        plant.RegisterCollisionGeometry(world, RigidTransform(),
                                        _mesh(heightmap_surface_obj(heightmap, mask),
                                              f"terrain_{material.name}.obj", directory),
                                        f"terrain_mesh_{material.name}", props)
        for index in np.unique(quad_band[mask]):
            visual = _mesh(drawn[m, index], f"terrain_visual_{material.name}_{index}.obj", directory)
            rgba = terrain_rgba((index + 0.5) * band, low, high, band=band,
                                material=material.name if by_material else None)
            plant.RegisterVisualGeometry(world, RigidTransform(), visual,
                                         f"terrain_mesh_{material.name}_{index}", rgba)
    return "mesh"


def make_robot_proximity_properties(*, hydroelastic: bool, material: GroundMaterial,
                                    friction: float = 1.0,
                                    resolution_hint: float = 0.03) -> ProximityProperties:
    """Contact properties for the robot's feet and trunk.

    Point contact (boxes): the foot is much stiffer than any ground, so the combined stiffness
    (springs in series) is the ground material's. Hydroelastic (mesh): the terrain is rigid, so
    the foot's hydroelastic modulus sets the stiffness; we take the ground material's.
    """
    props = ProximityProperties()
    AddContactMaterial(dissipation=material.hunt_crossley_dissipation,
                       point_stiffness=1.0e7,
                       friction=CoulombFriction(friction, friction), properties=props)
    if hydroelastic:
        AddCompliantHydroelasticProperties(resolution_hint=resolution_hint,
                                           hydroelastic_modulus=material.hydroelastic_modulus,
                                           properties=props)
    return props
