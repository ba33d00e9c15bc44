"""The capability networks' inputs (paper 000 section II-E.1, Fig. 4 and section III-B).

One place defines what a trial records and what a planner asks the model, so that the two can
never disagree:

* ``orthogonal`` and ``diagonal`` moves: a 20 x 20 body-frame height patch at 0.1 m spacing,
  a 2 m x 2 m window centred half way between the start and the target cell centres (so it
  covers both cells: the light yellow / light blue regions of Fig. 4);
* ``turn`` (45 deg in place): a 20 x 20 patch at 0.05 m spacing over the start cell;
* heights relative to the robot's standing ground: the median height of the start cell
  (sampled as the turn patch), so that the same step looks the same at any altitude;
* the start feet in the heading frame: ``R_z(yaw)^T (p_WF - (x, y, ground))``, (6, 3);
* ``d`` for the turn network: 0 turns left (+45 deg), 1 turns right (-45 deg).

Grid world conventions (paper 000 II-E.1): cells of ``CELL_SIZE``; headings are multiples of
45 deg, ``heading_index`` k in 0..7 meaning yaw = k * 45 deg; an orthogonal move goes 1 cell
along an axis-aligned heading (k even), a diagonal move one cell along each axis (k odd).
"""

from __future__ import annotations

import math

import numpy as np

from qz_drake.errors import bad_value

# The three networks of each topology (paper 000 Fig. 4).
KINDS: tuple[str, ...] = ("orthogonal", "diagonal", "turn")
# Grid world cell. [m]
CELL_SIZE = 1.0
# Samples along each side of a patch (paper 000 III-B).
PATCH_SIZE = 20
# Sample spacing of the move patches and the turn patch. [m]
MOVE_PATCH_SPACING = 0.1
TURN_PATCH_SPACING = 0.05
# Heading step of the grid world. [rad]
HEADING_STEP = math.pi / 4
# Turn directions d (paper 000 Eq. 8): 0 left (+45 deg), 1 right (-45 deg).
TURN_LEFT, TURN_RIGHT = 0, 1


def check_kind(kind: str, field: str = "kind") -> str:
    if kind not in KINDS:
        raise bad_value(field, kind, f"expected one of {', '.join(KINDS)}")
    return kind


def move_distance(kind: str) -> float:
    """Length of a move of this kind: one cell (orthogonal), one cell diagonally, 0 (turn). [m]"""
    check_kind(kind)
    return {"orthogonal": CELL_SIZE, "diagonal": CELL_SIZE * math.sqrt(2.0), "turn": 0.0}[kind]


def heading_yaw(heading_index) -> np.ndarray:
    """Yaw of heading index k (multiples of 45 deg). [rad]"""
    return np.asarray(heading_index, dtype=float) * HEADING_STEP


def kind_of_heading(heading_index: int) -> str:
    """The forward move along heading k: orthogonal for even k, diagonal for odd k."""
    return "orthogonal" if int(heading_index) % 2 == 0 else "diagonal"


def ground_reference(heightmap, x, y) -> np.ndarray:
    """The robot's standing ground at (x, y): the median height over its 1 m cell. [m]"""
    cell = heightmap.patch(x, y, np.zeros_like(np.asarray(x, dtype=float)), PATCH_SIZE,
                           TURN_PATCH_SPACING)
    return np.median(cell, axis=(-2, -1))


def sample_patches(heightmap, x, y, yaw, kind: str, ground=None) -> np.ndarray:
    """The network's height patches for robots at (x, y) heading yaw; (..., 20, 20) float32.

    x, y, yaw broadcast (e.g. arrays of shape (B,) give (B, 20, 20)); ``ground`` is the
    reference height (default: :func:`ground_reference`). Entry [i, j] is the body offset
    (u, v) of HeightMap.patch with u along the heading.
    """
    check_kind(kind)
    x, y, yaw = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (x, y, yaw)))
    ground = ground_reference(heightmap, x, y) if ground is None else np.asarray(ground, dtype=float)
    if kind == "turn":
        cx, cy, spacing = x, y, TURN_PATCH_SPACING
    else:
        half = 0.5 * move_distance(kind)
        cx, cy, spacing = x + half * np.cos(yaw), y + half * np.sin(yaw), MOVE_PATCH_SPACING
    patch = heightmap.patch(cx, cy, yaw, PATCH_SIZE, spacing)
    return (patch - ground[..., None, None]).astype(np.float32)


def feet_in_heading_frame(feet_W, x, y, yaw, ground) -> np.ndarray:
    """Start feet (..., 6, 3) in the heading frame, relative to (x, y, ground); float32."""
    feet_W = np.asarray(feet_W, dtype=float)
    x, y, yaw, ground = (np.asarray(a, dtype=float)[..., None] for a in (x, y, yaw, ground))
    dx, dy, dz = feet_W[..., 0] - x, feet_W[..., 1] - y, feet_W[..., 2] - ground
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * dx + s * dy, -s * dx + c * dy, dz], axis=-1).astype(np.float32)


def nominal_feet_W(heightmap, x, y, yaw, topology, foot_radius: float) -> np.ndarray:
    """The topology's nominal footholds on the terrain around (x, y) heading yaw, (..., 6, 3):
    what a planner assumes the feet are when it has no better guess."""
    x, y, yaw = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (x, y, yaw)))
    p_B = topology.footholds_B
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    fx = x[..., None] + c * p_B[:, 0] - s * p_B[:, 1]
    fy = y[..., None] + s * p_B[:, 0] + c * p_B[:, 1]
    return np.stack([fx, fy, heightmap.height(fx, fy) + foot_radius], axis=-1)


STANCES = ("nominal", "canonical")


def check_stance(stance: str, field: str = "stance") -> str:
    if stance not in STANCES:
        raise bad_value(field, stance, f"expected one of {', '.join(STANCES)}")
    return stance


def map_stance(terminal_stance: str) -> str:
    """The stance a planner's map assumes for a BLC whose missions end in ``terminal_stance``
    (BlcParameters.terminal_stance): "canonical" for "canonical", else "nominal"."""
    return "canonical" if terminal_stance == "canonical" else "nominal"


def canonical_feet_W(heightmap, x, y, yaw, topology, foot_radius: float, blc_params=None) -> np.ndarray:
    """The topology's canonical stance on the terrain around (x, y) heading yaw, (..., 6, 3):
    the stance a mission ends in with the BLC's ``terminal_stance = "canonical"``
    (trajopt/stance.py; the support field and tolerance of ``blc_params``, default
    BlcParameters()); a foot the rule leaves free stands on its nominal foothold."""
    from qz_drake.trajopt.parameters import BlcParameters
    from qz_drake.trajopt.stance import canonical_stance
    from qz_drake.trajopt.support import support_field
    from qz_drake.trajopt.terrain import GridTerrain

    p = blc_params or BlcParameters()
    support = None
    if p.enabled("support"):
        # One terrain per heightmap, so that its support field is computed once (support_field
        # caches it on the terrain) however many bands and topologies a map asks for.
        cache = heightmap.__dict__.setdefault("_canonical_terrain", {})
        terrain = cache.setdefault("grid", GridTerrain(heightmap))
        support = support_field(terrain, foot_radius + p.support_margin, p.support_drop)
    box = np.broadcast_to(np.asarray(topology.box_half_size, dtype=float), topology.footholds_B.shape)
    return canonical_stance(topology.footholds_B, box, x, y, yaw, heightmap, support, foot_radius,
                            p.terminal_foothold_tolerance).feet


def stance_feet_W(heightmap, x, y, yaw, topology, foot_radius: float, stance: str = "nominal") -> np.ndarray:
    """The feet a planner assumes at (x, y) heading yaw: ``stance`` "nominal" (nominal_feet_W)
    or "canonical" (canonical_feet_W)."""
    if check_stance(stance) == "canonical":
        return canonical_feet_W(heightmap, x, y, yaw, topology, foot_radius)
    return nominal_feet_W(heightmap, x, y, yaw, topology, foot_radius)


def grid_centres(heightmap, cell_size: float = CELL_SIZE, anchor=None) -> tuple[np.ndarray, np.ndarray]:
    """(xs, ys) of the grid world's cell centres over a heightmap: as many whole cells of
    ``cell_size`` as fit in the area the map's cells cover, from its lower-left corner (a
    20 m x 20 m map has 20 x 20 cells); with ``anchor`` (x, y), the grid is shifted so that
    the anchor (the robot's start) is a cell centre, keeping the cells that fit on the map.
    [m]"""
    if not (math.isfinite(float(cell_size)) and cell_size > 0):
        raise bad_value("cell_size", cell_size, "must be a positive number of metres")
    xmin, xmax, ymin, ymax = heightmap.bounds
    half = 0.5 * heightmap.resolution
    lo = np.array([xmin - half, ymin - half])
    hi = np.array([xmax + half, ymax + half])
    if anchor is not None:
        a = np.asarray(anchor, dtype=float).reshape(2)
        # The first centre at or past lo + cell / 2 on the anchor's lattice.
        first = a + np.ceil((lo + 0.5 * cell_size - a) / cell_size - 1e-9) * cell_size
    else:
        first = lo + 0.5 * cell_size
    counts = np.floor((hi - 0.5 * cell_size - first) / cell_size + 1e-9).astype(int) + 1
    if counts.min() < 1:
        raise bad_value("heightmap.bounds", heightmap.bounds, f"smaller than one {cell_size} m grid cell")
    return (first[0] + np.arange(counts[0]) * cell_size, first[1] + np.arange(counts[1]) * cell_size)


def mirror_legs(params=None) -> np.ndarray:
    """The leg permutation of the robot's mirror image in its sagittal plane (y -> -y): leg i
    of the mirrored robot is leg ``mirror_legs()[i]`` of the robot. Found from the hip
    positions, so that it follows the robot's geometry (Qingzhui: MF and MB map to themselves,
    RF <-> LF, RB <-> LB); a robot without that symmetry is an error."""
    from qz_drake.robot.params import DEFAULT_PARAMS

    hips = np.asarray((params or DEFAULT_PARAMS).hip_positions, dtype=float)
    mirrored = hips * np.array([1.0, -1.0, 1.0])
    distance = np.linalg.norm(mirrored[:, None, :] - hips[None, :, :], axis=-1)
    permutation = distance.argmin(axis=1)
    if distance.min(axis=1).max() > 1e-9 or len(set(permutation.tolist())) != len(hips):
        raise bad_value("params.hip_positions", hips.tolist(), "not symmetric about the body's x-z plane")
    return permutation


def mirror_inputs(patches, feet, direction=None, kind: str = "orthogonal"):
    """The network inputs of the same action on the mirror image of the terrain (y -> -y in
    the heading frame): the patches flipped across the heading, the feet mirrored (y negated,
    legs permuted by :func:`mirror_legs`) and, for a turn, the direction swapped (a left turn
    on the mirrored terrain is the right turn on the terrain).

    For a robot, topologies and gait that are all symmetric about the sagittal plane (tested
    in tests/capability/test_training.py for Qingzhui's six topologies and the tripod), the
    mirrored trial is the trial of the mirrored scene, with the same outcome: training on both
    doubles the data at no cost. Returns (patches, feet, direction) as new arrays.
    """
    check_kind(kind)
    patches = np.asarray(patches)
    feet = np.asarray(feet)
    # Entry [..., i, j] samples v = (j - (n - 1) / 2) * spacing across the heading: v -> -v.
    flipped = patches[..., :, ::-1].copy()
    mirrored_feet = feet[..., mirror_legs(), :].copy()
    mirrored_feet[..., 1] *= -1
    if direction is None:
        return flipped, mirrored_feet, None
    direction = np.asarray(direction)
    if kind == "turn":
        direction = np.where(direction == TURN_LEFT, TURN_RIGHT, TURN_LEFT).astype(direction.dtype)
    return flipped, mirrored_feet, direction.copy()
