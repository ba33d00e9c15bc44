"""Terrain: heightmaps, seeded generators, ground materials, Drake contact geometry."""

from qz_drake.terrain.generators import (TERRAIN_KINDS, grid_map_terrain, make_terrain,
                                         terrain_param_names)
from qz_drake.terrain.heightmap import HeightMap
from qz_drake.terrain.materials import MATERIALS, GroundMaterial, get_material

__all__ = ["HeightMap", "TERRAIN_KINDS", "make_terrain", "terrain_param_names", "grid_map_terrain",
           "MATERIALS", "GroundMaterial", "get_material"]
