"""Compiled sampling of the networks' height patches for whole maps (the planner's side).

``patches.sample_patches`` builds a patch with numpy's ``HeightMap.patch``: clear, but for a
whole map (every cell, eight headings, two patch kinds: 20 x 20 samples each) its temporaries
made the patch sampling a third of a 100 m plan (measured 2026-12-01: 14 s of 50 s). The kernel
here computes the same bilinear interpolation (HeightMap.height's quad, clamping and operation
order) in one compiled pass per patch, without temporaries. Training and the capability trials
keep using ``patches.sample_patches``; a test holds the two equal. The same kernel writing
float64 gives the cells' ground reference (``ground_reference_fast``, the median of the cell's
heights as ``patches.ground_reference`` takes it) without the half-gigabyte of numpy
temporaries a 100 m map's cells cost that way.
"""

from __future__ import annotations

import numba
import numpy as np

from qz_drake.capability import patches as P
from qz_drake.threads import set_numba_threads


@numba.njit(cache=True, parallel=True)
def _bilinear_patches(h, ox, oy, resolution, cx, cy, c, s, offsets, ground, out):
    # Queries split over the free cores (set_numba_threads): each patch is its own.
    rows, cols = h.shape
    n = offsets.shape[0]
    for q in numba.prange(cx.shape[0]):
        for i in range(n):
            du = offsets[i]
            for j in range(n):
                dv = offsets[j]
                x = cx[q] + c[q] * du - s[q] * dv
                y = cy[q] + s[q] * du + c[q] * dv
                u = (x - ox) / resolution
                v = (y - oy) / resolution
                uc = min(max(u, 0.0), cols - 1.0)
                vc = min(max(v, 0.0), rows - 1.0)
                i0 = min(int(uc), cols - 2)
                j0 = min(int(vc), rows - 2)
                fx = uc - i0
                fy = vc - j0
                z = (h[j0, i0] * (1 - fx) + h[j0, i0 + 1] * fx) * (1 - fy) \
                    + (h[j0 + 1, i0] * (1 - fx) + h[j0 + 1, i0 + 1] * fx) * fy
                out[q, i, j] = z - ground[q]


def sample_patches_fast(heightmap, x, y, yaw, kind: str, ground) -> np.ndarray:
    """The same patches as ``patches.sample_patches(heightmap, x, y, yaw, kind, ground)``,
    (..., 20, 20) float32, for finite queries on a map of at least 2 x 2 cells."""
    P.check_kind(kind)
    x, y, yaw, ground = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (x, y, yaw, ground)))
    shape = x.shape
    if kind == "turn":
        cx, cy, spacing = x, y, P.TURN_PATCH_SPACING
    else:
        half = 0.5 * P.move_distance(kind)
        cx, cy, spacing = x + half * np.cos(yaw), y + half * np.sin(yaw), P.MOVE_PATCH_SPACING
    offsets = (np.arange(P.PATCH_SIZE) - (P.PATCH_SIZE - 1) / 2.0) * spacing
    flat = [np.ascontiguousarray(a.reshape(-1)) for a in (cx, cy, np.cos(yaw), np.sin(yaw), ground)]
    # Written as float32 element by element: the same rounding as casting the float64 patch.
    out = np.empty((flat[0].size, P.PATCH_SIZE, P.PATCH_SIZE), dtype=np.float32)
    h = np.ascontiguousarray(heightmap.heights, dtype=float)
    set_numba_threads()
    _bilinear_patches(h, float(heightmap.origin[0]), float(heightmap.origin[1]),
                      float(heightmap.resolution), *flat[:4], offsets, flat[4], out)
    return out.reshape(shape + (P.PATCH_SIZE, P.PATCH_SIZE))


def ground_reference_fast(heightmap, x, y) -> np.ndarray:
    """``patches.ground_reference(heightmap, x, y)``, the same numbers, for finite queries on a
    map of at least 2 x 2 cells: the median of the 20 x 20 heights over each robot's cell."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    shape = x.shape
    n = x.size
    offsets = (np.arange(P.PATCH_SIZE) - (P.PATCH_SIZE - 1) / 2.0) * P.TURN_PATCH_SPACING
    cell = np.empty((n, P.PATCH_SIZE, P.PATCH_SIZE))
    h = np.ascontiguousarray(heightmap.heights, dtype=float)
    set_numba_threads()
    _bilinear_patches(h, float(heightmap.origin[0]), float(heightmap.origin[1]), float(heightmap.resolution),
                      np.ascontiguousarray(x.reshape(-1)), np.ascontiguousarray(y.reshape(-1)), np.ones(n),
                      np.zeros(n), offsets, np.zeros(n), cell)
    return np.median(cell, axis=(-2, -1)).reshape(shape)
