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
  point contact.

``"auto"`` chooses boxes when the map decomposes into at most ``max_boxes`` rectangles.
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import numpy as np
from pydrake.geometry import (AddCompliantHydroelasticProperties, AddContactMaterial,
                              AddRigidHydroelasticProperties, Box, Mesh, ProximityProperties)
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
_TERRAIN_RGBA = np.array([0.55, 0.6, 0.5, 1.0])
_MATERIAL_RGBA = {
    "concrete": np.array([0.62, 0.62, 0.6, 1.0]),
    "wood": np.array([0.65, 0.45, 0.25, 1.0]),
    "foam": np.array([0.35, 0.55, 0.8, 1.0]),
}


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


def point_contact_properties(material: GroundMaterial) -> ProximityProperties:
    props = ProximityProperties()
    AddContactMaterial(dissipation=material.hunt_crossley_dissipation,
                       point_stiffness=material.stiffness,
                       friction=CoulombFriction(material.static_friction, material.dynamic_friction),
                       properties=props)
    return props


def heightmap_surface_obj(heightmap, cell_mask: np.ndarray | None = None) -> str:
    """Wavefront OBJ text of the map's top surface (two triangles per pair of neighbouring
    cell centres, normals up). ``cell_mask`` (H-1, W-1) keeps only some quads."""
    h = np.asarray(heightmap.heights, dtype=float)
    H, W = h.shape
    xs = heightmap.origin[0] + heightmap.resolution * np.arange(W)
    ys = heightmap.origin[1] + heightmap.resolution * np.arange(H)
    X, Y = np.meshgrid(xs, ys)
    vertices = np.stack([X.ravel(), Y.ravel(), h.ravel()], axis=1)
    idx = np.arange(H * W).reshape(H, W) + 1  # OBJ indices are 1-based
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    quads = np.ones((H - 1, W - 1), dtype=bool) if cell_mask is None else cell_mask
    tri1 = np.stack([a[quads], b[quads], d[quads]], axis=1)
    tri2 = np.stack([a[quads], d[quads], c[quads]], axis=1)
    faces = np.concatenate([tri1, tri2])
    used = np.unique(faces)
    # Keep only the vertices the faces use, so each material's file is self-contained.
    remap = np.zeros(H * W + 1, dtype=np.int64)
    remap[used] = np.arange(1, len(used) + 1)
    lines = ["# qz_drake heightmap surface"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices[used - 1]]
    lines += [f"f {i} {j} {k}" for i, j, k in remap[faces]]
    return "\n".join(lines) + "\n"


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
    model hydroelastic-with-fallback (the station does both).
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
                                         _MATERIAL_RGBA.get(material.name, _TERRAIN_RGBA))
        return "boxes"
    if contact == "boxes":
        raise bad_value("terrain.contact", contact,
                        f"this map needs more than {MAX_FORCED_BOXES} boxes; use 'mesh' or 'auto'",
                        TerrainError)
    directory = Path(mesh_dir) if mesh_dir is not None else Path(tempfile.mkdtemp(prefix="qz_terrain_"))
    directory.mkdir(parents=True, exist_ok=True)
    # A quad takes the material of its lower-left cell.
    quad_material = (np.zeros(h.shape, dtype=np.int64) if labels is None else np.asarray(labels))[:-1, :-1]
    for m, material in enumerate(materials):
        mask = quad_material == m
        if not mask.any():
            continue
        path = directory / f"terrain_{material.name}.obj"
        path.write_text(heightmap_surface_obj(heightmap, mask))
        props = point_contact_properties(material)
        # Rigid terrain: the foot's compliance carries the material's stiffness (see
        # make_robot_proximity_properties); resolution_hint is unused for rigid meshes.
        AddRigidHydroelasticProperties(properties=props)
        mesh = Mesh(str(path))
        plant.RegisterCollisionGeometry(world, RigidTransform(), mesh, f"terrain_mesh_{material.name}", props)
        plant.RegisterVisualGeometry(world, RigidTransform(), mesh, f"terrain_mesh_{material.name}",
                                     _MATERIAL_RGBA.get(material.name, _TERRAIN_RGBA))
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
