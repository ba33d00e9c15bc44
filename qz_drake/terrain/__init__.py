"""Terrain: heightmaps, seeded generators, ground materials, Drake contact geometry."""

from qz_drake.terrain.generators import (BEHIND_START, DEFAULT_RESOLUTION, TERRAIN_KINDS, flat, gap,
                                         grid_map_terrain, long_range, make_terrain, material_floor,
                                         obstacles, pits, rough, slope, stairs, step, terrain_param_names,
                                         waves)
from qz_drake.terrain.heightmap import HeightMap
from qz_drake.terrain.materials import (FOOT_RADIUS, MATERIALS, NOMINAL_FOOT_LOAD, GroundMaterial,
                                        get_material, hydroelastic_modulus_for, make_ground_material)

__all__ = [
    "HeightMap",
    "TERRAIN_KINDS", "make_terrain", "terrain_param_names", "grid_map_terrain", "DEFAULT_RESOLUTION",
    "BEHIND_START", "flat", "slope", "stairs", "step", "gap", "pits", "waves", "rough", "obstacles",
    "long_range", "material_floor",
    "GroundMaterial", "MATERIALS", "get_material", "make_ground_material", "hydroelastic_modulus_for",
    "NOMINAL_FOOT_LOAD", "FOOT_RADIUS",
]
