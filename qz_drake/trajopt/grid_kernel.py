"""GridTerrain's heights and derivatives, compiled (numba): the bicubic Hermite interpolant of
terrain.py evaluated one point at a time, with the numpy form's operations in the numpy form's
order (``GridTerrain.height_derivatives_numpy``), so that every number is the same to the bit
and only the time changes: the BLC's guess, constraints and verdict query the map thousands of
times per solve, a few hundred points at a time, where numpy's per-call overhead was the cost."""

import numba
import numpy as np


def _grid_values(x, y, f, fx, fy, origin_x, origin_y, res, res2, out) -> bool:
    """GridTerrain's heights (out[0]) and, when out has six rows, their derivatives (h_x, h_y,
    h_xx, h_xy, h_yy) at points (x, y), one point at a time: the operations of
    ``GridTerrain.height_derivatives_numpy`` (``_patches``, ``_hermite_*``) in their order, so
    that every number is the same to the bit. False (nothing further written) at a NaN
    coordinate, which has no cell."""
    H, W = f.shape
    derivatives = out.shape[0] > 1
    for k in range(x.shape[0]):
        u = (x[k] - origin_x) / res
        v = (y[k] - origin_y) / res
        if u != u or v != v:
            return False
        inside_u = u > 0 and u < W - 1
        inside_v = v > 0 and v < H - 1
        u = min(max(u, 0.0), W - 1.0)
        v = min(max(v, 0.0), H - 1.0)
        i = min(int(np.floor(u)), W - 2)
        j = min(int(np.floor(v)), H - 2)
        s = u - i
        t = v - j
        s2, s3 = s * s, s * s * s
        t2, t3 = t * t, t * t * t
        # (phi_0, psi_0, phi_1, psi_1) along x (p) and y (q): _hermite_values.
        p0, p1, p2, p3 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        q0, q1, q2, q3 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2
        # Corner data in _hermite_combine's order: (a, b) = (0, 0), (0, 1), (1, 0), (1, 1).
        f00, x00, y00 = f[j, i], fx[j, i], fy[j, i]
        f01, x01, y01 = f[j + 1, i], fx[j + 1, i], fy[j + 1, i]
        f10, x10, y10 = f[j, i + 1], fx[j, i + 1], fy[j, i + 1]
        f11, x11, y11 = f[j + 1, i + 1], fx[j + 1, i + 1], fy[j + 1, i + 1]
        out[0, k] = _combine(p0, p1, p2, p3, q0, q1, q2, q3, f00, x00, y00, f01, x01, y01,
                             f10, x10, y10, f11, x11, y11)
        if not derivatives:
            continue
        ps2 = s * s  # _hermite_slopes and _hermite_curvatures along x ...
        d0, d1, d2, d3 = 6 * ps2 - 6 * s, 3 * ps2 - 4 * s + 1, -6 * ps2 + 6 * s, 3 * ps2 - 2 * s
        c0, c1, c2, c3 = 12 * s - 6, 6 * s - 4, -12 * s + 6, 6 * s - 2
        qs2 = t * t  # ... and along y
        e0, e1, e2, e3 = 6 * qs2 - 6 * t, 3 * qs2 - 4 * t + 1, -6 * qs2 + 6 * t, 3 * qs2 - 2 * t
        g0, g1, g2, g3 = 12 * t - 6, 6 * t - 4, -12 * t + 6, 6 * t - 2
        hx = _combine(d0, d1, d2, d3, q0, q1, q2, q3, f00, x00, y00, f01, x01, y01,
                      f10, x10, y10, f11, x11, y11) if inside_u else 0.0
        hy = _combine(p0, p1, p2, p3, e0, e1, e2, e3, f00, x00, y00, f01, x01, y01,
                      f10, x10, y10, f11, x11, y11) if inside_v else 0.0
        hxx = _combine(c0, c1, c2, c3, q0, q1, q2, q3, f00, x00, y00, f01, x01, y01,
                       f10, x10, y10, f11, x11, y11) if inside_u else 0.0
        hxy = _combine(d0, d1, d2, d3, e0, e1, e2, e3, f00, x00, y00, f01, x01, y01,
                       f10, x10, y10, f11, x11, y11) if inside_u and inside_v else 0.0
        hyy = _combine(p0, p1, p2, p3, g0, g1, g2, g3, f00, x00, y00, f01, x01, y01,
                       f10, x10, y10, f11, x11, y11) if inside_v else 0.0
        out[1, k] = hx / res
        out[2, k] = hy / res
        out[3, k] = hxx / res2
        out[4, k] = hxy / res2
        out[5, k] = hyy / res2
    return True


def _combine(p0, p1, p2, p3, q0, q1, q2, q3, f00, x00, y00, f01, x01, y01, f10, x10, y10,
                f11, x11, y11):
    """terrain._hermite_combine at one point, its sum in the same order."""
    out = 0.0
    out = out + (p0 * q0 * f00 + p1 * q0 * x00 + p0 * q1 * y00)
    out = out + (p0 * q2 * f01 + p1 * q2 * x01 + p0 * q3 * y01)
    out = out + (p2 * q0 * f10 + p3 * q0 * x10 + p2 * q1 * y10)
    out = out + (p2 * q2 * f11 + p3 * q2 * x11 + p2 * q3 * y11)
    return out



def _highest_cells(x, y, dx, dy, heights, origin_x, origin_y, res, out) -> bool:
    """out[k]: the highest of the raw cells under the points (x[k] + dx[m], y[k] + dy[m]), a
    point taking the cell it lies in, clamped to the grid (leg_clearance.RawCells); the same
    arithmetic as the numpy form. False at a NaN coordinate."""
    H, W = heights.shape
    for k in range(x.shape[0]):
        best = -np.inf
        for m in range(dx.shape[0]):
            u = np.rint(((x[k] + dx[m]) - origin_x) / res)
            v = np.rint(((y[k] + dy[m]) - origin_y) / res)
            if u != u or v != v:
                return False
            ix = int(min(max(u, 0.0), W - 1.0))
            iy = int(min(max(v, 0.0), H - 1.0))
            best = max(best, heights[iy, ix])
        out[k] = best
    return True


_combine = numba.njit(cache=True, inline="always")(_combine)
grid_values = numba.njit(cache=True, nogil=True)(_grid_values)
highest_cells = numba.njit(cache=True, nogil=True)(_highest_cells)
