"""The legs' links in the BLC: points of each thigh and shank from the body pose and the foot,
with exact first derivatives (issue 34; paper 002 Eq. 1-6, paper 000 Fig. 2).

The BLC plans the body and the feet; a leg's links follow from its inverse kinematics. For a
Qingzhui leg (hip abduction j0, thigh j1, shank j2 through the parallelogram) the leg plane
contains j0's axis ``a`` (radially outwards, fixed in the body) and the hip-to-foot vector
``d``; within that plane the knee lies on both the thigh's circle about the hip (radius l1) and
the shank's about the foot (radius l2)::

    u = d / |d|,  along = (l1^2 - l2^2 + |d|^2) / (2 |d|),  off = sqrt(l1^2 - along^2)
    w = unit(a - (a . u) u)                         (in the plane, normal to u, outwards)
    knee = hip + along u + bend off w               (bend +1: knee out, -1: knee in)

which is paper 002's closed-form IK (``robot.kinematics.leg_inverse_kinematics``) written in
world coordinates, so the same knee the tracker commands. Points on the links are fixed
distances along the thigh (from the hip) and the shank (from the knee). Everything is
vectorised over samples and legs and carried in forward mode: each quantity with its gradient
with respect to the nine inputs (CoM r, roll-pitch-yaw, foot p) of its sample, so a
constraint's Jacobian is exact (tests check it against finite differences).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from qz_drake.trajopt.constraints import rotation_derivatives, rotation_from_rpy

# Gradient columns: CoM position, roll-pitch-yaw, foot position.
COM, RPY, FOOT = slice(0, 3), slice(3, 6), slice(6, 9)
# The knee's distance from the hip-foot line never goes below this (a stretched leg): keeps
# the square root's derivative finite. [m]
_MIN_OFFSET = 1e-3


@dataclasses.dataclass(frozen=True)
class LinkPoints:
    """Where on each leg the BLC looks: a point is (link, distance along it) with link 0 the
    thigh (distance from the hip) and 1 the shank (distance from the knee)."""

    # (J,) link of each point: 0 thigh, 1 shank.
    links: tuple[int, ...]
    # (J,) distance of each point along its link. [m]
    distances: tuple[float, ...]
    # Display names of the points, e.g. "thigh 0.22 m".
    names: tuple[str, ...]

    @staticmethod
    def along(thigh: tuple[float, ...], shank: tuple[float, ...]) -> "LinkPoints":
        """Points at the given distances along the thigh and the shank. [m]"""
        links = (0,) * len(thigh) + (1,) * len(shank)
        distances = tuple(float(d) for d in (*thigh, *shank))
        names = tuple(f"{'thigh' if k == 0 else 'shank'} {d:.2f} m" for k, d in zip(links, distances))
        return LinkPoints(links, distances, names)

    @property
    def num_points(self) -> int:
        return len(self.links)


def link_geometry(robot) -> dict:
    """The link data of a RobotModel's legs as arrays, or None if a leg has no links:
    hips (L, 3), axes (L, 3), thigh (L,), shank (L,), bend (L,)."""
    legs = robot.legs
    if any(leg.links is None for leg in legs):
        return None
    return dict(hips=np.array([leg.hip_position for leg in legs], dtype=float),
                axes=np.array([leg.links.radial_axis for leg in legs], dtype=float),
                thigh=np.array([leg.links.thigh_length for leg in legs], dtype=float),
                shank=np.array([leg.links.shank_length for leg in legs], dtype=float),
                bend=np.array([leg.links.knee_bend for leg in legs], dtype=float))


def knee_positions(geometry: dict, com, rpy, feet, with_gradient: bool = True):
    """Hips and knees of every leg at every sample.

    Args:
        geometry: ``link_geometry(robot)``.
        com: (n, 3) CoM positions, world. [m]
        rpy: (n, 3) body roll, pitch, yaw. [rad]
        feet: (n, L, 3) foot positions, world. [m]

    Returns ``(hip, knee, grad_hip, grad_knee)``: positions (n, L, 3) and, with_gradient, their
    gradients (n, L, 3, 9) with respect to (com, rpy, that leg's foot) of the same sample
    (else None)."""
    com = np.asarray(com, dtype=float)
    rpy = np.asarray(rpy, dtype=float)
    feet = np.asarray(feet, dtype=float)
    n, L = feet.shape[:2]
    l1 = geometry["thigh"][None, :]
    l2 = geometry["shank"][None, :]
    bend = geometry["bend"][None, :]
    R = rotation_from_rpy(rpy)
    hip = com[:, None, :] + np.einsum("nij,lj->nli", R, geometry["hips"])
    axis = np.einsum("nij,lj->nli", R, geometry["axes"])
    d = feet - hip
    dist = np.linalg.norm(d, axis=-1)
    u = d / dist[..., None]
    along = 0.5 * ((l1 * l1 - l2 * l2) / dist + dist)
    off = np.sqrt(np.maximum(l1 * l1 - along * along, _MIN_OFFSET ** 2))
    c = (axis * u).sum(-1)
    w_raw = axis - c[..., None] * u
    w_norm = np.linalg.norm(w_raw, axis=-1)
    w = w_raw / w_norm[..., None]
    knee = hip + along[..., None] * u + (bend * off)[..., None] * w
    if not with_gradient:
        return hip, knee, None, None

    eye = np.eye(3)
    dR = rotation_derivatives(rpy)  # (n, 3, 3, angle)
    g_hip = np.zeros((n, L, 3, 9))
    g_hip[..., COM] = eye
    g_hip[..., RPY] = np.einsum("nijk,lj->nlik", dR, geometry["hips"])[:, :, :, :]
    g_axis = np.zeros((n, L, 3, 9))
    g_axis[..., RPY] = np.einsum("nijk,lj->nlik", dR, geometry["axes"])
    g_d = -g_hip
    g_d[..., FOOT] += eye
    g_dist = np.einsum("nli,nlik->nlk", u, g_d)
    g_u = (g_d - u[..., :, None] * g_dist[..., None, :]) / dist[..., None, None]
    g_along = (0.5 - 0.5 * (l1 * l1 - l2 * l2) / (dist * dist))[..., None] * g_dist
    stretched = l1 * l1 - along * along <= _MIN_OFFSET ** 2
    g_off = np.where(stretched[..., None], 0.0, (-along / off)[..., None] * g_along)
    g_c = np.einsum("nli,nlik->nlk", axis, g_u) + np.einsum("nli,nlik->nlk", u, g_axis)
    g_w_raw = g_axis - u[..., :, None] * g_c[..., None, :] - c[..., None, None] * g_u
    g_w = (g_w_raw - w[..., :, None] * np.einsum("nli,nlik->nlk", w, g_w_raw)[..., None, :]) \
        / w_norm[..., None, None]
    g_knee = (g_hip + u[..., :, None] * g_along[..., None, :] + along[..., None, None] * g_u
              + bend[..., None, None] * (w[..., :, None] * g_off[..., None, :]
                                         + off[..., None, None] * g_w))
    return hip, knee, g_hip, g_knee


def link_points(geometry: dict, points: LinkPoints, com, rpy, feet, with_gradient: bool = True):
    """The points of every leg's links: (n, L, J, 3) and, with_gradient, their gradients
    (n, L, J, 3, 9) with respect to (com, rpy, that leg's foot) of the same sample."""
    feet = np.asarray(feet, dtype=float)
    hip, knee, g_hip, g_knee = knee_positions(geometry, com, rpy, feet, with_gradient)
    links = np.asarray(points.links)
    dist = np.asarray(points.distances, dtype=float)
    thigh = links == 0
    # Each point is start + s (end - start): the thigh's from hip to knee, the shank's from
    # knee to foot, s the distance over the link's length.
    s = np.where(thigh[None, :], dist[None, :] / geometry["thigh"][:, None],
                 dist[None, :] / geometry["shank"][:, None])  # (L, J)
    start = np.where(thigh[None, None, :, None], hip[:, :, None, :], knee[:, :, None, :])
    end = np.where(thigh[None, None, :, None], knee[:, :, None, :], feet[:, :, None, :])
    pts = start + s[None, :, :, None] * (end - start)
    if not with_gradient:
        return pts, None
    n, L = feet.shape[:2]
    g_foot = np.zeros((n, L, 3, 9))
    g_foot[..., FOOT] = np.eye(3)
    g_start = np.where(thigh[None, None, :, None, None], g_hip[:, :, None], g_knee[:, :, None])
    g_end = np.where(thigh[None, None, :, None, None], g_knee[:, :, None], g_foot[:, :, None])
    grad = g_start + s[None, :, :, None, None] * (g_end - g_start)
    return pts, grad
