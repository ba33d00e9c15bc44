"""Planning: grid search and A* on cost maps (paper 003); more planners join here."""

from qz_drake.planning.astar import AStarConfig, AStarResult, astar, astar_grid
from qz_drake.planning.grid_search import (MOVE_HEADINGS, MOVE_LENGTHS, MOVES, GridPath, grid_search,
                                           search_directional)

__all__ = ["GridPath", "grid_search", "search_directional", "MOVES", "MOVE_LENGTHS", "MOVE_HEADINGS",
           "AStarConfig", "AStarResult", "astar", "astar_grid"]
