"""The canonical stance of a pose (issue 54): where the feet stand when a mission ends.

A planner's map asks the capability model about a cell with the robot standing in some stance,
and the BLC decides whether the next mission plans largely from the stance the last one left
(validation walks: none of 401 missions from six level feet refused, 55 of 83 from none). With
``BlcParameters.terminal_stance = "canonical"`` every mission ends in the stance this module
defines for its target pose, and the map asks about the same stance, so the two agree by
construction rather than by luck.

The rule, one for both sides, deterministic and cheap enough to evaluate for every cell and
heading of a map:

* each foot's *nominal* foothold at the pose (the topology's footholds in the pose's heading
  frame);
* a foot on ground without support (trajopt/support.py: an edge, a riser, ground steeper than
  the friction cone) is moved to the centre of the nearest cell at least ``clear`` from such
  ground, the same field the BLC's support constraint uses;
* a foot that would then leave its kinematic box (shrunk by ``clear``) stays where it is and is
  *free*: the BLC leaves it where the plan puts it (no canonical foothold exists for it).
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class CanonicalStance:
    """Feet of the canonical stance at one or more poses."""

    # Foot-sphere centres on the terrain, (..., L, 3); a free foot's nominal foothold. [m]
    feet: np.ndarray
    # Which feet have a canonical foothold (False: free), (..., L).
    fixed: np.ndarray
    # Which feet were moved off unsupported ground, (..., L).
    moved: np.ndarray


def canonical_stance(footholds_B, box_half_sizes, x, y, yaw, terrain, support, foot_radius: float,
                     clear: float) -> CanonicalStance:
    """The canonical stance of poses (x, y, yaw) (broadcast together, shape ``...``).

    footholds_B: (L, >=2) nominal footholds in the frame of the pose (its x, y the pose's
    origin, its x axis the heading); box_half_sizes: (L, >=2) the kinematic boxes' half sizes
    around them; terrain: anything with ``height(x, y)``; support: a support.SupportField, or
    None where all ground is supported; clear: how far from unsupported ground a moved foot
    stands, and how far inside its box it must stay. [m]"""
    footholds_B = np.asarray(footholds_B, dtype=float)
    box = np.asarray(box_half_sizes, dtype=float)[:, :2]
    x, y, yaw = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (x, y, yaw)))
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    u, w = footholds_B[:, 0], footholds_B[:, 1]
    fx = x[..., None] + c * u - s * w
    fy = y[..., None] + s * u + c * w
    shape = fx.shape
    if support is None:
        moved = np.zeros(shape, dtype=bool)
        fixed = np.ones(shape, dtype=bool)
    else:
        xy = support.nearest_clear(fx, fy, clear)
        dx, dy = xy[..., 0] - fx, xy[..., 1] - fy
        moved = (dx != 0.0) | (dy != 0.0)
        # The move in the pose's frame must keep the foot inside its box, ``clear`` from its sides.
        du, dw = c * dx + s * dy, -s * dx + c * dy
        fixed = (np.abs(du) <= box[:, 0] - clear) & (np.abs(dw) <= box[:, 1] - clear)
        take = moved & fixed
        fx, fy = np.where(take, xy[..., 0], fx), np.where(take, xy[..., 1], fy)
        moved = take
    fz = np.asarray(terrain.height(fx.ravel(), fy.ravel()), dtype=float).reshape(shape) + foot_radius
    return CanonicalStance(np.stack([fx, fy, fz], axis=-1), fixed, moved)
