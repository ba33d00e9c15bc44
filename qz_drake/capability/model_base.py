"""What every capability model shares, whatever learned it (issue 37): the model folder's
format, the errors, the checks of a query's inputs, the card-based properties and the map of
every cell and heading (``predict_map``). ``CapabilityModel`` (qz_drake.capability.model, the
paper's CNNs) and ``BoostedCapabilityModel`` (qz_drake.capability.boosted) both build on
:class:`CapabilityModelBase`; qz_drake.capability.model re-exports these names.

Importing this module imports neither torch nor scikit-learn.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np

from qz_drake.capability import patches as P
from qz_drake.errors import QzError, bad_value

MODEL_FORMAT = "qz_drake.capability_model"
FORMAT_VERSION = 1
MODEL_CARD = "model.json"

class CapabilityModelError(QzError, ValueError):
    """A capability model directory, weights file or card is missing, foreign or inconsistent."""


def _error(field: str, value, why: str) -> CapabilityModelError:
    return bad_value(field, value, why, CapabilityModelError)


def check_patches(patches) -> tuple[np.ndarray, tuple]:
    """(patches as float32, batch shape) of (..., 20, 20) height patches; a QzError otherwise."""
    patches = np.asarray(patches, dtype=np.float32)
    if patches.shape[-2:] != (P.PATCH_SIZE, P.PATCH_SIZE):
        raise _error("patches", f"array of shape {patches.shape}", f"expected (..., {P.PATCH_SIZE}, {P.PATCH_SIZE})")
    return patches, patches.shape[:-2]


def check_direction(kind: str, direction, batch: tuple) -> np.ndarray | None:
    """A turn's d broadcast to the batch (0 left, 1 right); None for a move, which takes none."""
    if kind == "turn":
        if direction is None:
            raise _error("direction", None, "the turn network needs d (0 left, 1 right)")
        d = np.broadcast_to(np.asarray(direction), batch)
        if not np.isin(d, (P.TURN_LEFT, P.TURN_RIGHT)).all():
            raise _error("direction", np.unique(d).tolist(), "expected 0 (left) or 1 (right)")
        return d
    if direction is not None:
        raise _error("direction", direction, f"only the turn network takes a direction, not {kind}")
    return None


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _replace(path: Path, write) -> None:
    """Writes a file aside and renames it into place: a file on disk is always whole."""
    import os

    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def distinct_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, inverse) of an (n, k) array: ``first`` the index of one row of each distinct
    row, ``inverse`` (n,) the position in ``first`` of each row's, so that
    ``rows[first[inverse]]`` equals ``rows`` exactly (rows with NaN stand alone).

    Rows are grouped by a random projection and every row is then compared with its group's
    first, entry by entry: a row that differs from it (two rows with the same projection) gets
    a group of its own, so the answer is exact whatever the projection."""
    rows = np.asarray(rows)
    n = rows.shape[0]
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    weights = np.random.default_rng(0).normal(size=rows.shape[1]).astype(rows.dtype, copy=False)
    keys = rows @ weights if rows.dtype.kind == "f" else rows.astype(np.float64) @ weights
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1).astype(np.int64)
    same = np.empty(n, bool)
    step = max(1, (1 << 22) // max(rows.shape[1], 1))
    for a in range(0, n, step):
        b = min(a + step, n)
        same[a:b] = (rows[a:b] == rows[first[inverse[a:b]]]).all(axis=1)
    alone = np.flatnonzero(~same)
    if len(alone):
        inverse[alone] = len(first) + np.arange(len(alone))
        first = np.concatenate([first, alone])
    return first.astype(np.int64), inverse


class CapabilityModelBase:
    """The answers of a capability model that come from its card and its ``success_all``:
    fingerprints, the (topology, kind) it covers, each one's share of refusals among its
    training failures, the inputs of a query from a HeightMap and the whole map. A subclass sets
    ``self.card`` (the model.json dict) and ``self._networks`` (keyed by (topology, kind)) and
    answers ``network``, ``success`` and ``success_all``.
    """

    card: dict
    _networks: dict

    # -- properties ---------------------------------------------------------------------------
    @property
    def fingerprint(self) -> str:
        return self.card.get("fingerprint", "")

    @property
    def fingerprints(self) -> dict:
        return dict(self.card.get("fingerprints", {}))

    @property
    def networks(self) -> list[tuple[str, str]]:
        """(topology, kind) of the networks this model has."""
        return sorted(self._networks)

    def plan_failure_share(self, topology: str, kind: str) -> float | None:
        """Of the network's failed training trials, the share in which the BLC found no plan
        (the robot stood where it was) rather than the walk failing the verdict; None when the
        network's card does not say (a model trained before the cards held it, or random)."""
        card = self.card.get("cards", {}).get(f"{topology}/{kind}", {})
        counts = card.get("failures") or {}
        total = int(counts.get("planning", 0)) + int(counts.get("execution", 0))
        return int(counts["planning"]) / total if total else None

    def has_network(self, topology: str, kind: str) -> bool:
        return (topology, kind) in self._networks

    @staticmethod
    def query_inputs(heightmap, x, y, heading_index, kind: str, topology: str, *, ground=None,
                     stance: str = "nominal"):
        """(patches, feet) for robots at (x, y) with heading index k (yaw = k * 45 deg),
        standing in the topology's ``stance`` (patches.stance_feet_W: "nominal" footholds or
        the "canonical" stance); x, y and k broadcast. Vectorised over every query (built on
        qz_drake.capability.patches)."""
        from qz_drake.robot.params import DEFAULT_PARAMS
        from qz_drake.robot.topology import get_topology

        x, y, k = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float),
                                      np.asarray(heading_index))
        yaw = P.heading_yaw(k)
        ground = P.ground_reference(heightmap, x, y) if ground is None else ground
        patches = P.sample_patches(heightmap, x, y, yaw, kind, ground)
        feet_W = P.stance_feet_W(heightmap, x, y, yaw, get_topology(topology), DEFAULT_PARAMS.foot_radius, stance)
        return patches, P.feet_in_heading_frame(feet_W, x, y, yaw, ground)

    def map_success(self, heightmap, topologies=None, *, cell_size: float = P.CELL_SIZE,
                    stance: str = "nominal") -> "CapabilityMap":
        """Every action's success probability from every cell and heading (see predict_map)."""
        return predict_map(self, heightmap, topologies, cell_size=cell_size, stance=stance)


@dataclasses.dataclass
class CapabilityMap:
    """Success probabilities of every action from every (cell, heading) of a grid world."""

    # (nx,) and (ny,) cell centres. [m]
    xs: np.ndarray
    ys: np.ndarray
    # The topologies of the first axis.
    topologies: tuple[str, ...]
    # (T, 8, ny, nx): moving one cell forward along heading k (orthogonal or diagonal network).
    forward: np.ndarray
    # (T, 8, ny, nx): turning 45 deg left (d = 0) / right (d = 1) in place from heading k.
    turn_left: np.ndarray
    turn_right: np.ndarray
    # Grid cell. [m]
    cell_size: float = P.CELL_SIZE
    # (T, 3) per topology and kind (orthogonal, diagonal, turn): the share of the network's
    # failures in which the BLC found no plan (CapabilityModel.plan_failure_share); NaN where
    # the model does not say; None: not known at all (a stub model).
    plan_failure_share: np.ndarray | None = None
    # (T, 8, ny, nx) each, with a two-output model (networks.NetworkConfig.factored): the
    # chance that the BLC plans the action (the rest of its failures are falls); None otherwise.
    forward_plan: np.ndarray | None = None
    turn_left_plan: np.ndarray | None = None
    turn_right_plan: np.ndarray | None = None
    # (T, 8, ny, nx) each, with ensembles (networks.CapabilityEnsemble): the standard deviation
    # of the members' success; None otherwise.
    forward_spread: np.ndarray | None = None
    turn_left_spread: np.ndarray | None = None
    turn_right_spread: np.ndarray | None = None

    @property
    def queries(self) -> int:
        """Network evaluations behind the map."""
        return int(self.forward.size + self.turn_left.size + self.turn_right.size)


@dataclasses.dataclass
class MapInputs:
    """The networks' inputs for every cell and heading of a grid world (sample_map_inputs)."""

    # (nx,) and (ny,) cell centres. [m]
    xs: np.ndarray
    ys: np.ndarray
    cell_size: float
    # (8, ny, nx, 20, 20) forward-move patches (orthogonal for even k, diagonal for odd k). [m]
    move_patches: np.ndarray
    # (8, ny, nx, 20, 20) turn patches. [m]
    turn_patches: np.ndarray
    # topology -> (8, ny, nx, 6, 3) the assumed stance's feet in the heading frame. [m]
    feet: dict


def pose_inputs(heightmap, x: float, y: float, yaw: float, kind: str, feet_W) -> tuple[np.ndarray, np.ndarray]:
    """One query's inputs at a pose: the (20, 20) height patch of ``kind`` and the feet
    ``feet_W`` (6, 3, world) in the heading frame, both against the ground under the body
    (patches.ground_reference), as the map's are for every cell."""
    ground = float(P.ground_reference(heightmap, x, y))
    return (P.sample_patches(heightmap, x, y, yaw, kind, ground=ground),
            P.feet_in_heading_frame(np.asarray(feet_W, dtype=float), x, y, yaw, ground))


def sample_map_inputs(heightmap, topologies, *, cell_size: float = P.CELL_SIZE, anchor=None,
                      rows: slice | None = None, stance: str = "nominal") -> MapInputs:
    """Patches (once per kind: they do not depend on the topology) and each topology's feet in
    ``stance`` (patches.stance_feet_W) for every cell and heading, vectorised over all of them
    (built on patches.py); ``rows``: only the grid's rows of cells (ys) in that slice."""
    from qz_drake.capability.map_sampling import ground_reference_fast, sample_patches_fast
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology

    xs, ys = P.grid_centres(heightmap, cell_size, anchor)
    if rows is not None:
        ys = ys[rows]
    # Grid arrays (8, ny, nx): heading index first, as the planner's states.
    k, gy, gx = np.meshgrid(np.arange(8), ys, xs, indexing="ij")
    yaw = P.heading_yaw(k)
    ground = np.broadcast_to(ground_reference_fast(heightmap, gx[0], gy[0]), k.shape)
    even = k % 2 == 0
    move_patches = np.empty(k.shape + (P.PATCH_SIZE, P.PATCH_SIZE), np.float32)
    for kind, mask in (("orthogonal", even), ("diagonal", ~even)):
        move_patches[mask] = sample_patches_fast(heightmap, gx[mask], gy[mask], yaw[mask], kind, ground[mask])
    turn_patches = sample_patches_fast(heightmap, gx, gy, yaw, "turn", ground)
    feet = {t: P.feet_in_heading_frame(P.stance_feet_W(heightmap, gx, gy, yaw, get_topology(t),
                                                       DEFAULT_PARAMS.foot_radius, stance), gx, gy, yaw, ground)
            for t in topologies}
    return MapInputs(xs=xs, ys=ys, cell_size=float(cell_size), move_patches=move_patches,
                     turn_patches=turn_patches, feet=feet)


def predict_map(model, heightmap, topologies=None, *, cell_size: float = P.CELL_SIZE,
                anchor=None, stance: str = "nominal") -> CapabilityMap:
    """Every action's success probability from every cell and heading of the grid world.

    ``model`` is anything with CapabilityModel's ``success`` (a stub in tests). The inputs come
    from :func:`sample_map_inputs`; each network then sees all its queries in one batched
    call. The robot is assumed to stand in the topology's ``stance``: "nominal" footholds, or
    the "canonical" stance a mission ends in with the BLC's terminal_stance "canonical"
    (patches.stance_feet_W). ``anchor`` (x, y) puts a cell centre there (the robot's start;
    see patches.grid_centres).
    """
    P.check_stance(stance, "capability_mdp.stance")
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    topologies = tuple(topologies or TOPOLOGY_NAMES)
    if hasattr(model, "network"):
        for t in topologies:
            for kind in P.KINDS:
                model.network(t, kind)  # a missing network fails before any work
    xs, ys = P.grid_centres(heightmap, cell_size, anchor)
    band = max(1, MAP_BAND_QUERIES // (8 * len(xs)))
    if not getattr(model, "queries_independent", False) or band >= len(ys):
        return evaluate_map(model, sample_map_inputs(heightmap, topologies, cell_size=cell_size, anchor=anchor,
                                                     stance=stance))
    # A model whose every query's answer is its own (the boosted trees): the map a band of rows
    # at a time, so that a 100 m map's patches never all exist at once (half a gigabyte).
    parts = [evaluate_map(model, sample_map_inputs(heightmap, topologies, cell_size=cell_size, anchor=anchor,
                                                   rows=slice(a, a + band), stance=stance))
             for a in range(0, len(ys), band)]
    first = parts[0]
    joined = {}
    for field in dataclasses.fields(CapabilityMap):
        value = getattr(first, field.name)
        if isinstance(value, np.ndarray) and value.ndim == 4:  # (T, 8, ny, nx)
            joined[field.name] = np.concatenate([getattr(part, field.name) for part in parts], axis=2)
        else:
            joined[field.name] = value
    joined["ys"] = ys
    return CapabilityMap(**joined)


# Queries (cells x headings) a band of a map holds when the model answers each on its own.
MAP_BAND_QUERIES = 16384


def evaluate_map(model, inputs: MapInputs) -> CapabilityMap:
    """The networks on a MapInputs: forward, turn left and turn right for each topology."""
    topologies = tuple(inputs.feet)
    shape = (len(topologies),) + inputs.move_patches.shape[:3]
    even = (np.arange(8) % 2 == 0)
    forward, left, right = np.empty(shape), np.empty(shape), np.empty(shape)
    if hasattr(model, "success_all"):  # the topologies' first convolutions as one
        plans = np.full((3,) + shape, np.nan)  # forward, left, right
        spreads = np.full((3,) + shape, np.nan)
        for kind, mask in (("orthogonal", even), ("diagonal", ~even)):
            moves = model.success_all(inputs.move_patches[mask], {t: inputs.feet[t][mask] for t in topologies}, kind)
            for i, t in enumerate(topologies):
                forward[i][mask] = moves[t][0]
                if moves[t][1] is not None:
                    plans[0, i][mask] = moves[t][1]
                if moves[t][2] is not None:
                    spreads[0, i][mask] = moves[t][2]
        turns = model.success_all(inputs.turn_patches, inputs.feet, "turn")
        for i, t in enumerate(topologies):
            (left[i], right[i]), plan, spread = turns[t]
            if plan is not None:
                plans[1, i], plans[2, i] = plan
            if spread is not None:
                spreads[1, i], spreads[2, i] = spread
        factored = not np.isnan(plans).any()
        ensembles = not np.isnan(spreads).any()
        return CapabilityMap(xs=inputs.xs, ys=inputs.ys, topologies=topologies, forward=forward, turn_left=left,
                             turn_right=right, cell_size=inputs.cell_size,
                             plan_failure_share=_shares(model, topologies),
                             forward_plan=plans[0] if factored else None, turn_left_plan=plans[1] if factored else None,
                             turn_right_plan=plans[2] if factored else None,
                             forward_spread=spreads[0] if ensembles else None,
                             turn_left_spread=spreads[1] if ensembles else None,
                             turn_right_spread=spreads[2] if ensembles else None)
    for i, t in enumerate(topologies):
        feet = inputs.feet[t]
        forward[i][even] = model.success(inputs.move_patches[even], feet[even], "orthogonal", t)
        forward[i][~even] = model.success(inputs.move_patches[~even], feet[~even], "diagonal", t)
        # A model with only ``success`` (a stub): both directions in one call.
        left[i], right[i] = model.success(np.stack([inputs.turn_patches] * 2), np.stack([feet] * 2), "turn", t,
                                          direction=np.array([P.TURN_LEFT, P.TURN_RIGHT])[:, None, None, None])
    return CapabilityMap(xs=inputs.xs, ys=inputs.ys, topologies=topologies, forward=forward, turn_left=left,
                         turn_right=right, cell_size=inputs.cell_size, plan_failure_share=_shares(model, topologies))


def _shares(model, topologies) -> np.ndarray | None:
    """(T, 3) the model's plan_failure_share per topology and kind (NaN where it does not say);
    None for a model without them (a stub)."""
    if not hasattr(model, "plan_failure_share"):
        return None
    return np.array([[np.nan if (v := model.plan_failure_share(t, kind)) is None else v for kind in P.KINDS]
                     for t in topologies], dtype=float).reshape(len(topologies), len(P.KINDS))
