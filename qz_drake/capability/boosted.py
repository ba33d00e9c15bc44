"""The capability as gradient-boosted trees: one learner for every topology and kind (issue 37).

Why trees and not the paper's 18 CNNs, measured on the episode dataset (BENCHMARKS
"capability-networks"): a mission's refusal ("the BLC found no plan") is mostly how the robot
stands when it starts (how many feet stand level with the ground under the body, a foot down a
step) and the terrain it meets; on held-out episode scenes, gradient boosting on simple patch
and feet features ranks the refusals at ROC AUC 0.96, a pooled CNN with the same topology and
kind inputs at 0.89, an MLP on the boosting's own features at 0.88: the trees cut single foot
heights at thresholds, which the networks smooth over. Each of the 18 networks saw 1/18 of the
data; here one learner sees all of it, with the topology and kind as inputs.

Inputs of a query (``features``): the height patch as 4 x 4 block means and its range, max, min
and standard deviation; the kind and topology one-hot; the turn direction d (0 for moves); the
start feet in the heading frame (18 numbers), as the networks take them.

Outputs: three outcomes as one softmax, walked / no plan / executed and failed (the order of
training.OUTCOMES), fitted with the multinomial log loss (a proper score). The iteration count
is chosen on the validation scenes' log loss.

Ensemble: ``members`` learners, each on a bootstrap of the training scenes (whole scenes, so
that a member never sees half of a scene's correlated records) from its own seed; the model's
outcomes are the members' mean and its spread the standard deviation of their P(walked), read
by the planner as the networks' ensemble spread (capability_mdp, ``pessimism``).

Storage without pickle: the trees are exported from scikit-learn's HistGradientBoostingClassifier
into flat arrays (feature, threshold, children, leaf value) saved as one ``.npz`` with a JSON
card, and evaluated by a compiled loop of our own (:func:`_raw_scores`; numba), tested equal to
scikit-learn's ``predict_proba``. Loading needs numpy and numba only.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from qz_drake.capability import patches as P
from qz_drake.capability.model_base import (FORMAT_VERSION, MODEL_CARD, MODEL_FORMAT, CapabilityModelBase, _error,
                                            _replace, _sha256, check_direction, check_patches, distinct_rows)
from qz_drake.errors import ConfigError, bad_value
from qz_drake.robot.topology import TOPOLOGY_NAMES

LEARNER = "boosted"
WEIGHTS_FILE = "boosted.npz"
BLOCKS = 4
# Feature names, in the column order of ``features``.
FEATURE_NAMES = tuple([f"block_{i}_{j}" for i in range(BLOCKS) for j in range(BLOCKS)]
                      + ["patch_range", "patch_max", "patch_min", "patch_std"]
                      + [f"kind_{k}" for k in P.KINDS] + [f"topology_{t}" for t in TOPOLOGY_NAMES]
                      + ["direction"] + [f"foot_{leg}_{c}" for leg in range(6) for c in "xyz"])
# The order of the three outcomes (training.OUTCOMES).
OUTCOMES = ("walked", "no_plan", "failed")
# Iterations a learner grows between two looks at its validation loss.
BOOST_CHUNK = 25
_ARRAYS = ("feature", "threshold", "left", "right", "leaf", "value", "missing_left")


def features(patches, feet, kind, topology, direction=None, *, patch_part=None) -> np.ndarray:
    """(n, len(FEATURE_NAMES)) float64 inputs of n queries.

    Args:
        patches: (n, 20, 20) height patches relative to the standing ground [m].
        feet: (n, 6, 3) start feet in the heading frame [m].
        kind, topology: one name for every query, or (n,) arrays of names.
        direction: turns' d (0 left, 1 right), scalar or (n,); None or -1 for moves (0 here).
        patch_part: :func:`patch_features` of the patches, when the caller has them already
            (the same patches asked for several topologies).
    """
    patches = np.asarray(patches)
    n = patches.shape[0]
    part = patch_features(patches) if patch_part is None else patch_part
    feet = np.asarray(feet, dtype=np.float64)
    if feet.shape != (n, 6, 3):
        raise bad_value("feet", f"array of shape {feet.shape}", f"expected ({n}, 6, 3) to match the patches")
    kind = np.broadcast_to(np.asarray(kind).astype(str), (n,))
    topology = np.broadcast_to(np.asarray(topology).astype(str), (n,))
    for name, values, allowed in (("kind", kind, P.KINDS), ("topology", topology, TOPOLOGY_NAMES)):
        unknown = sorted(set(np.unique(values)) - set(allowed))
        if unknown:
            raise bad_value(name, unknown, f"expected one of {', '.join(allowed)}")
    d = np.zeros(n) if direction is None else np.maximum(np.broadcast_to(np.asarray(direction, float), (n,)), 0.0)
    return np.column_stack([part, kind[:, None] == np.asarray(P.KINDS)[None],
                            topology[:, None] == np.asarray(TOPOLOGY_NAMES)[None],
                            d, feet.reshape(n, 18)]).astype(np.float64)


def patch_features(patches) -> np.ndarray:
    """(n, 20) the patch's columns of :func:`features`: 4 x 4 block means, range, max, min, std."""
    patches = np.asarray(patches, dtype=np.float64)
    n = patches.shape[0]
    if patches.shape[1:] != (P.PATCH_SIZE, P.PATCH_SIZE):
        raise bad_value("patches", f"array of shape {patches.shape}", f"expected (n, {P.PATCH_SIZE}, {P.PATCH_SIZE})")
    side = P.PATCH_SIZE // BLOCKS
    blocks = patches.reshape(n, BLOCKS, side, BLOCKS, side).mean(axis=(2, 4)).reshape(n, -1)
    top, bottom = patches.max(axis=(1, 2)), patches.min(axis=(1, 2))
    return np.column_stack([blocks, top - bottom, top, bottom, patches.std(axis=(1, 2))])


def _over_free_cores(function, array: np.ndarray, queries: int, axis: int = 0) -> np.ndarray:
    """``function(array)``, the array's first axis cut into pieces evaluated over the free
    cores and joined along ``axis`` of the results (each row's answer is its own, so the
    numbers are those of one call). The compiled loops and numpy's release the GIL. Pieces,
    not halves, taken as threads come free: a map's distinct groups come sorted by their
    projection, so one half can be flat ground, cheap, and the other rough (halves kept one
    core idle for a third of a 100 m map)."""
    threads = min(inference_threads(), queries // PARALLEL_ROWS)
    if threads <= 1:
        return function(array)
    from concurrent.futures import ThreadPoolExecutor

    pieces = min(PIECES_PER_THREAD * threads, max(threads, queries // PARALLEL_ROWS))
    with ThreadPoolExecutor(threads) as pool:
        return np.concatenate(list(pool.map(function, np.array_split(array, pieces))), axis=axis)


# -- the trees as arrays -------------------------------------------------------------------------
@dataclasses.dataclass
class Trees:
    """One boosted learner's trees as flat arrays (every tree's nodes one after the other).

    ``roots`` (iterations, classes) is each tree's first node; a node is a leaf (``leaf``) with
    its ``value``, or splits on ``feature`` at ``threshold`` (x <= threshold goes ``left``,
    NaN goes left where ``missing_left``). The raw score of class c is ``baseline[c]`` plus the
    leaves reached in the trees of column c; the outcomes are their softmax.
    """

    baseline: np.ndarray  # (classes,)
    roots: np.ndarray  # (iterations, classes) int64
    feature: np.ndarray  # (nodes,) int64
    threshold: np.ndarray  # (nodes,) float64
    left: np.ndarray  # (nodes,) int64, global node index
    right: np.ndarray  # (nodes,) int64
    leaf: np.ndarray  # (nodes,) bool
    value: np.ndarray  # (nodes,) float64
    missing_left: np.ndarray  # (nodes,) bool

    @classmethod
    def from_sklearn(cls, model, iterations: int | None = None) -> "Trees":
        """The first ``iterations`` (default all) of a fitted HistGradientBoostingClassifier with
        numerical features only."""
        predictors = getattr(model, "_predictors", None)
        baseline = getattr(model, "_baseline_prediction", None)
        if predictors is None or baseline is None:
            raise ConfigError("scikit-learn's HistGradientBoostingClassifier no longer exposes _predictors and "
                              "_baseline_prediction: this scikit-learn cannot be exported (boosted.Trees)")
        predictors = predictors[: len(predictors) if iterations is None else int(iterations)]
        parts, roots, offset = [], np.zeros((len(predictors), len(predictors[0]) if predictors else 0), np.int64), 0
        for i, per_class in enumerate(predictors):
            for c, tree in enumerate(per_class):
                nodes = tree.nodes
                if np.any(nodes["is_categorical"]):
                    raise ConfigError("boosted.Trees exports numerical splits only")
                roots[i, c] = offset
                parts.append((nodes, offset))
                offset += len(nodes)
        if not parts:
            raise ConfigError("boosted.Trees: the learner has no trees")
        cat = np.concatenate([n for n, _ in parts])
        shift = np.concatenate([np.full(len(n), o, np.int64) for n, o in parts])
        leaf = cat["is_leaf"].astype(bool)
        return cls(baseline=np.asarray(baseline, np.float64).reshape(-1), roots=roots,
                   feature=cat["feature_idx"].astype(np.int64), threshold=cat["num_threshold"].astype(np.float64),
                   left=np.where(leaf, -1, cat["left"].astype(np.int64) + shift),
                   right=np.where(leaf, -1, cat["right"].astype(np.int64) + shift), leaf=leaf,
                   value=cat["value"].astype(np.float64), missing_left=cat["missing_go_to_left"].astype(bool))

    def arrays(self, prefix: str = "") -> dict:
        out = {f"{prefix}baseline": self.baseline, f"{prefix}roots": self.roots}
        out.update({f"{prefix}{name}": getattr(self, name) for name in _ARRAYS})
        return out

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "") -> "Trees":
        trees = cls(**{name: np.asarray(arrays[f"{prefix}{name}"]) for name in ("baseline", "roots") + _ARRAYS})
        n = len(trees.feature)
        if (any(len(getattr(trees, a)) != n for a in _ARRAYS) or trees.roots.ndim != 2
                or trees.roots.shape[1] != len(trees.baseline) or trees.roots.size == 0
                or trees.roots.min() < 0 or trees.roots.max() >= n
                or np.any(trees.left[~trees.leaf] < 0) or np.any(trees.left >= n) or np.any(trees.right >= n)):
            raise ConfigError(f"boosted trees {prefix or ''}: inconsistent arrays (not a file this code wrote)")
        return trees

    @property
    def iterations(self) -> int:
        return int(self.roots.shape[0])

    def raw(self, X: np.ndarray) -> np.ndarray:
        """(n, classes) raw scores of inputs X (n, features)."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        return _raw_scores(X, self.baseline, self.roots, self.feature, self.threshold, self.left, self.right,
                           self.leaf, self.value, self.missing_left)

    def probabilities(self, X: np.ndarray) -> np.ndarray:
        """(n, classes) softmax of the raw scores."""
        return softmax(self.raw(X))


def softmax(raw: np.ndarray) -> np.ndarray:
    """The softmax over the last axis (the classes). Written class by class: numpy's
    reductions over a 3-long last axis cost ~20 ns a row; for fewer than 8 classes the sums
    are added in numpy's order ((e0 + e1) + e2), so the numbers are those of ``e.sum(-1)``."""
    raw = np.asarray(raw, dtype=np.float64)
    classes = raw.shape[-1]
    top = raw[..., 0].copy()
    for c in range(1, classes):
        np.maximum(top, raw[..., c], out=top)
    e = np.exp(raw - top[..., None])
    if classes >= 8:  # numpy sums these pairwise
        return e / e.sum(axis=-1, keepdims=True)
    total = e[..., 0].copy()
    for c in range(1, classes):
        total += e[..., c]
    return e / total[..., None]


def sigmoid(raw: np.ndarray) -> np.ndarray:
    """The logistic function: a binary learner's probability of its class 1 from its raw score."""
    return 1.0 / (1.0 + np.exp(-np.asarray(raw, dtype=np.float64)))


def with_plan(outcomes: np.ndarray, planned: np.ndarray) -> np.ndarray:
    """The three outcomes (..., 3) with the chance that the BLC plans taken from a plan learner
    (``planned`` (...)): no plan 1 - planned; walked and failed share the rest as the outcome
    learner shares its own walked and failed (an even split where it gives them nothing)."""
    executed = outcomes[..., 0] + outcomes[..., 2]
    walked = np.divide(outcomes[..., 0], executed, out=np.full(executed.shape, 0.5), where=executed > 0)
    out = np.empty(np.shape(outcomes))
    out[..., 0] = planned * walked
    out[..., 1] = 1.0 - planned
    out[..., 2] = planned * (1.0 - walked)
    return out


def _raw_scores_py(X, baseline, roots, feature, threshold, left, right, leaf, value, missing_left):
    out = np.empty((X.shape[0], roots.shape[1]))
    for s in range(X.shape[0]):
        for c in range(roots.shape[1]):
            total = baseline[c]
            for i in range(roots.shape[0]):
                node = roots[i, c]
                while not leaf[node]:
                    x = X[s, feature[node]]
                    if x != x:  # NaN
                        node = left[node] if missing_left[node] else right[node]
                    elif x <= threshold[node]:
                        node = left[node]
                    else:
                        node = right[node]
                total += value[node]
            out[s, c] = total
    return out


# The columns of a query that depend on its patch and kind only (patch features, kind one-hot):
# shared by a map cell's queries in every topology and turn direction.
SHARED_FEATURES = 20 + len(P.KINDS)
# Patches whose queries (every topology and turn direction) success_all evaluates at once:
# about 75 MB of features for turns in six topologies.
MAP_CHUNK = 16384
# Pieces per thread a map's groups are cut into, taken as threads come free.
PIECES_PER_THREAD = 8
# Fewest distinct queries per thread worth a thread of their own (a map has ~20 000; one
# query costs ~0.2 ms over five learners' trees).
PARALLEL_ROWS = 1024


def inference_threads() -> int:
    """Threads for the trees: the free cores, as torch's (qz_drake.threads.torch_threads;
    ``QZ_TORCH_THREADS`` sets it), so that two threads never fight over one busy core."""
    from qz_drake.threads import torch_threads

    return torch_threads()


try:  # compiled: ~1 us per tree and query against ~1 ms in Python
    import numba

    _raw_scores = numba.njit(cache=True, nogil=True)(_raw_scores_py)
except ImportError:  # pragma: no cover - numba is a dependency
    numba = None
    _raw_scores = _raw_scores_py


# -- every learner's trees at once: QuickScorer ---------------------------------------------------
# The most leaves a tree may have for ForestScorer (one bit each in a 64-bit word).
SCORER_MAX_LEAVES = 64
# Rows ForestScorer looks at together for the features that fail the same splits in all of them.
SCORER_CHUNK = 256
# x & -x isolates the lowest set bit; times this de Bruijn constant, its top six bits name it.
_DE_BRUIJN = 0x03F79D71B4CB0A89
_LOW_BIT = np.zeros(64, np.int64)
for _bit in range(64):
    _LOW_BIT[((1 << _bit) * _DE_BRUIJN & 0xFFFFFFFFFFFFFFFF) >> 58] = _bit


def _leaf_ranges_py(roots, left, right, leaf, first, last, order, tree_of):
    """For every node under ``roots`` (all -1 on entry): the in-order numbers, within its tree,
    of the first and last leaf under it (``first``, ``last``), a leaf's own number (``order``)
    and its tree, numbered as ``roots.flat`` (``tree_of``)."""
    stack = np.empty(len(left) + 1, np.int64)
    for t in range(roots.size):
        count = 0
        stack[0] = roots.flat[t]
        top = 1
        while top > 0:  # post-order, left before right: leaves are numbered left to right
            node = stack[top - 1]
            tree_of[node] = t
            if leaf[node]:
                order[node] = count
                first[node] = count
                last[node] = count
                count += 1
                top -= 1
            elif first[left[node]] < 0:
                stack[top] = left[node]
                top += 1
            elif first[right[node]] < 0:
                stack[top] = right[node]
                top += 1
            else:
                first[node] = first[left[node]]
                last[node] = last[right[node]]
                top -= 1


def _fail_splits_py(state, x, f, start, threshold, tree, mask):
    """ANDs into ``state`` the masks of feature f's splits that x fails (x > threshold); the
    splits are sorted by threshold, so the failed ones come first."""
    for k in range(start[f], start[f + 1]):
        if x > threshold[k]:
            state[tree[k]] &= mask[k]
        else:
            break


def _same_splits_py(values, start, threshold, f) -> bool:
    """Whether every value (none NaN) lies between the same two of feature f's thresholds:
    then each fails the same splits."""
    lo = values[0]
    hi = lo
    if lo != lo:
        return False
    for x in values[1:]:
        if x != x:
            return False
        if x < lo:
            lo = x
        elif x > hi:
            hi = x
    splits = threshold[start[f]:start[f + 1]]
    return np.searchsorted(splits, lo) == np.searchsorted(splits, hi)


def _add_leaves_py(alive, leaf_value, tree_member, tree_class, baseline, low_bit, out, s):
    """out[:, s] = the raw scores of the trees' exit leaves: each tree's leftmost live leaf;
    trees in (member, iteration, class) order, so each score adds its trees in the order
    Trees.raw does (the same floats)."""
    for m in range(out.shape[0]):
        for c in range(out.shape[2]):
            out[m, s, c] = baseline[m, c]
    for k in range(alive.shape[0]):
        v = alive[k]
        low = v & (~v + np.uint64(1))
        out[tree_member[k], s, tree_class[k]] += leaf_value[k, low_bit[(low * np.uint64(_DE_BRUIJN)) >> np.uint64(58)]]


def _fixed_columns_py(block, offset, start, threshold, tree, mask, state, varying) -> int:
    """The columns of ``block`` (rows, columns; column j is feature offset + j) whose values
    all fail the same splits are applied once, to ``state`` (the rows' common start); the others'
    indices go to ``varying``. Returns how many vary."""
    count = 0
    for j in range(block.shape[1]):
        if _same_splits(block[:, j], start, threshold, offset + j):
            _fail_splits(state, block[0, j], offset + j, start, threshold, tree, mask)
        else:
            varying[count] = j
            count += 1
    return count


def _vary_columns_py(state, row, offset, varying, count, start, threshold, tree, mask):
    """Applies a row's varying columns (``varying[:count]``, features offset + j) to ``state``."""
    for i in range(count):
        j = varying[i]
        _fail_splits(state, row[j], offset + j, start, threshold, tree, mask)


def _forest_scores_py(X, start, threshold, tree, mask, leaf_value, tree_member, tree_class, baseline,
                      low_bit, chunk, out):
    """QuickScorer's pass over rows X: out (members, n, classes) raw scores (a row with NaN
    gets a number here that the caller replaces)."""
    n = X.shape[0]
    trees = leaf_value.shape[0]
    alive = np.empty(trees, np.uint64)
    common = np.empty(trees, np.uint64)
    varying = np.empty(X.shape[1], np.int64)
    for a in range(0, n, chunk):
        b = min(a + chunk, n)
        # A feature whose values in these rows all fail the same splits (a map block's kind,
        # topology and direction, its nominal feet along x and y) is applied once, to the
        # rows' common start.
        common[:] = np.uint64(0xFFFFFFFFFFFFFFFF)
        count = _fixed_columns(X[a:b], 0, start, threshold, tree, mask, common, varying)
        for s in range(a, b):
            alive[:] = common
            _vary_columns(alive, X[s], 0, varying, count, start, threshold, tree, mask)
            _add_leaves(alive, leaf_value, tree_member, tree_class, baseline, low_bit, out, s)


def _grouped_scores_py(shared, variants, start, threshold, tree, mask, leaf_value, tree_member, tree_class,
                       baseline, low_bit, chunk, out):
    """QuickScorer's pass over groups of rows that share their first columns: row (p, v) is
    shared[p] followed by variants[p, v]. out (members, n * V, classes), row p * V + v."""
    n, V = variants.shape[0], variants.shape[1]
    split = shared.shape[1]
    trees = leaf_value.shape[0]
    common = np.empty(trees, np.uint64)
    per_variant = np.empty((V, trees), np.uint64)
    shared_varying = np.empty(split, np.int64)
    varying = np.empty((V, variants.shape[2]), np.int64)
    counts = np.empty(V, np.int64)
    state = np.empty(trees, np.uint64)
    alive = np.empty(trees, np.uint64)
    for a in range(0, n, chunk):
        b = min(a + chunk, n)
        # The columns that fail the same splits in all these groups, applied once: shared ones
        # (the kind) to the common start, each variant's (its topology, direction and nominal
        # feet along x and y) to that variant's.
        common[:] = np.uint64(0xFFFFFFFFFFFFFFFF)
        shared_count = _fixed_columns(shared[a:b], 0, start, threshold, tree, mask, common, shared_varying)
        for v in range(V):
            per_variant[v, :] = common
            counts[v] = _fixed_columns(variants[a:b, v], split, start, threshold, tree, mask, per_variant[v],
                                       varying[v])
        for p in range(a, b):
            # The group's shared columns once (a map cell's patch: every topology and turn
            # direction reads the same), then each variant's own.
            state[:] = np.uint64(0xFFFFFFFFFFFFFFFF)
            _vary_columns(state, shared[p], 0, shared_varying, shared_count, start, threshold, tree, mask)
            for v in range(V):
                for k in range(trees):
                    alive[k] = state[k] & per_variant[v, k]
                _vary_columns(alive, variants[p, v], split, varying[v], counts[v], start, threshold, tree, mask)
                _add_leaves(alive, leaf_value, tree_member, tree_class, baseline, low_bit, out, p * V + v)


if numba is not None:
    _leaf_ranges = numba.njit(cache=True)(_leaf_ranges_py)
    _fail_splits = numba.njit(cache=True, nogil=True)(_fail_splits_py)
    _same_splits = numba.njit(cache=True, nogil=True)(_same_splits_py)
    _add_leaves = numba.njit(cache=True, nogil=True)(_add_leaves_py)
    _fixed_columns = numba.njit(cache=True, nogil=True)(_fixed_columns_py)
    _vary_columns = numba.njit(cache=True, nogil=True)(_vary_columns_py)
    _forest_scores = numba.njit(cache=True, nogil=True)(_forest_scores_py)
    _grouped_scores = numba.njit(cache=True, nogil=True)(_grouped_scores_py)
else:  # pragma: no cover - numba is a dependency
    _leaf_ranges, _fail_splits, _same_splits, _add_leaves = _leaf_ranges_py, _fail_splits_py, _same_splits_py, _add_leaves_py
    _fixed_columns, _vary_columns = _fixed_columns_py, _vary_columns_py
    _forest_scores, _grouped_scores = _forest_scores_py, _grouped_scores_py


class ForestScorer:
    """The raw scores of several learners (an ensemble's members) in one pass, by QuickScorer
    (Lucchese et al., "QuickScorer: a fast algorithm to rank documents with additive ensembles
    of regression trees", SIGIR 2015): each tree's leaves are bits of a word; every split on a
    feature, sorted by threshold, carries the mask that clears its left subtree's leaves; a row
    ANDs the masks of the splits it fails (x > threshold: a prefix of each feature's list) and
    exits every tree at its leftmost live leaf. No branch depends on a tree's shape, which is
    where the node-by-node walk spends its time on trees 11-20 levels deep.

    The sums are those of :meth:`Trees.raw`, bit for bit (each score adds its trees' leaves in
    iteration order). Rows with a NaN take :meth:`Trees.raw` (a missing value may go right).
    """

    def __init__(self, members: list):
        members = list(members)
        classes = {int(t.roots.shape[1]) for t in members}
        if len(classes) != 1:
            raise ConfigError("ForestScorer: the learners have different class counts")
        self.members, self.classes = members, classes.pop()
        rows, thresholds, trees, masks, values, owners, columns = [], [], [], [], [], [], []
        offset = 0
        for m, t in enumerate(members):
            n = len(t.feature)
            first, last, order, tree_of = (np.full(n, -1, np.int64) for _ in range(4))
            roots = np.ascontiguousarray(t.roots, dtype=np.int64)  # (iterations, classes)
            _leaf_ranges(roots, t.left, t.right, t.leaf, first, last, order, tree_of)
            if np.any(tree_of < 0):
                raise ConfigError("ForestScorer: nodes outside every tree (not a file this code wrote)")
            tree_of = tree_of + offset  # trees numbered across the members
            width = last[roots.reshape(-1)] - first[roots.reshape(-1)] + 1
            if width.max() > SCORER_MAX_LEAVES:
                raise ConfigError(f"ForestScorer: a tree has {int(width.max())} leaves "
                                  f"(at most {SCORER_MAX_LEAVES})")
            internal = np.flatnonzero(~t.leaf)
            lo, hi = first[t.left[internal]], last[t.left[internal]]
            span = hi - lo + 1
            left_bits = np.where(span >= 64, np.uint64(0xFFFFFFFFFFFFFFFF),
                                 (np.uint64(1) << span.astype(np.uint64)) - np.uint64(1)) << lo.astype(np.uint64)
            rows.append(t.feature[internal])
            thresholds.append(t.threshold[internal])
            trees.append(tree_of[internal])
            masks.append(~left_bits)
            value = np.zeros((roots.size, SCORER_MAX_LEAVES))
            leaves = np.flatnonzero(t.leaf)
            value[tree_of[leaves] - offset, order[leaves]] = t.value[leaves]
            values.append(value)
            owners.append(np.full(roots.size, m, np.int64))
            columns.append(np.tile(np.arange(self.classes, dtype=np.int64), roots.shape[0]))
            offset += roots.size
        feature = np.concatenate(rows)
        threshold = np.concatenate(thresholds)
        by = np.lexsort((threshold, feature))
        self.features = int(feature.max()) + 1 if feature.size else 0
        self.start = np.searchsorted(feature[by], np.arange(self.features + 1)).astype(np.int64)
        self.threshold = np.ascontiguousarray(threshold[by])
        self.tree = np.ascontiguousarray(np.concatenate(trees)[by])
        self.mask = np.ascontiguousarray(np.concatenate(masks)[by])
        self.leaf_value = np.concatenate(values)
        self.tree_member = np.concatenate(owners)
        self.tree_class = np.concatenate(columns)
        self.baseline = np.stack([t.baseline for t in members])

    def _starts(self, columns: int) -> np.ndarray:
        """Each of ``columns`` features' first split (and the end): columns past the last one
        any tree splits on have none (the kernels visit every column of the rows)."""
        return np.concatenate([self.start, np.full(max(columns - self.features, 0), self.start[-1])])

    @classmethod
    def of(cls, members: list) -> "ForestScorer | None":
        """A scorer of these learners, or None where a tree has too many leaves for it."""
        try:
            return cls(members)
        except ConfigError:
            return None

    def raw(self, X: np.ndarray) -> np.ndarray:
        """(members, n, classes) raw scores of rows X (n, features)."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        out = np.empty((len(self.members), X.shape[0], self.classes))
        if X.shape[1] < self.features:
            raise bad_value("X", f"array of shape {X.shape}", f"expected at least {self.features} columns")
        _forest_scores(X, self._starts(X.shape[1]), self.threshold, self.tree, self.mask, self.leaf_value,
                       self.tree_member, self.tree_class, self.baseline, _LOW_BIT, SCORER_CHUNK, out)
        missing = np.flatnonzero(np.isnan(X).any(axis=1))
        if missing.size:
            for m, t in enumerate(self.members):
                out[m, missing] = t.raw(X[missing])
        return out

    def raw_grouped(self, shared: np.ndarray, variants: np.ndarray) -> np.ndarray:
        """(members, n, V, classes) raw scores of the rows (shared[p], variants[p, v]): groups
        of V rows whose first ``shared.shape[1]`` columns are the same (a map cell's patch in
        every topology and turn direction), those columns' splits taken once per group. The
        numbers of :meth:`raw` on the rows written out."""
        shared = np.ascontiguousarray(shared, dtype=np.float64)
        variants = np.ascontiguousarray(variants, dtype=np.float64)
        n, V = variants.shape[:2]
        if shared.ndim != 2 or variants.ndim != 3 or shared.shape[0] != n or shared.shape[1] + variants.shape[2] < self.features:
            raise bad_value("variants", f"arrays of shapes {shared.shape} and {variants.shape}",
                            f"expected (n, k) and (n, V, m) with k + m >= {self.features} columns")
        out = np.empty((len(self.members), n * V, self.classes))
        _grouped_scores(shared, variants, self._starts(shared.shape[1] + variants.shape[2]), self.threshold, self.tree, self.mask, self.leaf_value,
                        self.tree_member, self.tree_class, self.baseline, _LOW_BIT, SCORER_CHUNK, out)
        missing = np.flatnonzero((np.isnan(shared).any(axis=1)[:, None] | np.isnan(variants).any(axis=2)).reshape(-1))
        if missing.size:
            rows = np.concatenate([np.repeat(shared, V, axis=0), variants.reshape(n * V, -1)], axis=1)[missing]
            for m, t in enumerate(self.members):
                out[m, missing] = t.raw(rows)
        return out.reshape(len(self.members), n, V, self.classes)

    def probabilities(self, X: np.ndarray) -> np.ndarray:
        """(members, n, classes) every learner's softmax (:func:`softmax`'s numbers)."""
        return softmax(self.raw(X))


# -- training ------------------------------------------------------------------------------------
@dataclasses.dataclass
class BoostedConfig:
    """How the boosted capability model is trained; saved in its card."""

    # Seed of the scene split (training.split_scenes), the bootstraps and the learners.
    seed: int = 0
    # Train / validation / test fractions of the scenes.
    split: list[float] = dataclasses.field(default_factory=lambda: [0.70, 0.15, 0.15])
    # Learners in the ensemble, each on a bootstrap of the training scenes (1: one learner on
    # all of them).
    members: int = 5
    # Most boosting iterations; the kept count is the one with the lowest validation log loss,
    # and growing stops once that loss has not improved for ``patience`` iterations.
    max_iter: int = 400
    patience: int = 50
    learning_rate: float = 0.05
    max_leaf_nodes: int = 31
    min_samples_leaf: int = 20
    l2_regularization: float = 1.0
    # Train on every training record and its mirror image (patches.mirror_inputs), as the
    # networks do: the robot and gait are symmetric about the sagittal plane.
    mirror: bool = True

    def check(self) -> "BoostedConfig":
        if len(self.split) != 3 or any(not (f >= 0) for f in self.split) or not math.isclose(sum(self.split), 1.0):
            raise bad_value("boosted.split", self.split, "expected three fractions >= 0 summing to 1")
        if min(self.split[:2]) <= 0:
            raise bad_value("boosted.split", self.split, "train and validation fractions must be positive")
        for name in ("members", "max_iter", "patience", "max_leaf_nodes", "min_samples_leaf"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise bad_value(f"boosted.{name}", value, "must be a positive whole number")
        if self.max_leaf_nodes < 2:
            raise bad_value("boosted.max_leaf_nodes", self.max_leaf_nodes, "must be at least 2")
        if not (self.learning_rate > 0 and self.l2_regularization >= 0):
            raise bad_value("boosted.learning_rate", self.learning_rate, "must be positive (l2_regularization >= 0)")
        if not isinstance(self.mirror, bool):
            raise bad_value("boosted.mirror", self.mirror, "expected true or false")
        return self


def record_inputs(arrays: dict, rows: np.ndarray, mirror: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(X, source) of dataset rows: their features and, for each row of X, the dataset row it
    came from; with ``mirror``, the rows followed by their mirror images (the same source)."""
    rows = np.asarray(rows, dtype=np.int64)
    kind = np.asarray(arrays["kind"]).astype(str)[rows]
    topology = np.asarray(arrays["topology"]).astype(str)[rows]
    direction = np.asarray(arrays["direction"])[rows]
    patch, feet = np.asarray(arrays["patch"])[rows], np.asarray(arrays["feet"])[rows]
    X = [features(patch, feet, kind, topology, direction)]
    source = [rows]
    if mirror:
        for k in np.unique(kind):
            m = kind == k
            mp, mf, md = P.mirror_inputs(patch[m], feet[m], direction[m], k)
            X.append(features(mp, mf, k, topology[m], md))
            source.append(rows[m])
    return np.concatenate(X), np.concatenate(source)


def record_labels(arrays: dict, source: np.ndarray, labels: str = "outcomes") -> np.ndarray:
    """The labels of dataset rows ``source``: the outcome index (``labels`` "outcomes") or
    whether the BLC planned (1) or not ("plan")."""
    from qz_drake.capability.training import outcome_classes

    planned = np.asarray(arrays["blc_success"])[source]
    if labels == "outcomes":
        return outcome_classes(np.asarray(arrays["success"])[source], planned)
    return planned.astype(np.int64)


def record_features(arrays: dict, rows: np.ndarray, mirror: bool = False,
                    labels: str = "outcomes") -> tuple[np.ndarray, np.ndarray]:
    """(X, label) of dataset rows (record_inputs, record_labels)."""
    X, source = record_inputs(arrays, rows, mirror)
    return X, record_labels(arrays, source, labels)


def _fit_member(X, y, Xv, yv, config: BoostedConfig, seed: int, outcomes=OUTCOMES):
    """One learner of ``outcomes`` (the three, or the plan learner's ("no_plan", "planned")),
    grown ``BOOST_CHUNK`` iterations at a time until the validation log loss has not improved
    for ``config.patience`` iterations (or ``max_iter``), then cut at its best iteration.
    Returns (Trees, best iteration, validation log loss)."""
    from sklearn.ensemble import HistGradientBoostingClassifier

    if len(np.unique(y)) < len(outcomes):
        missing = sorted(set(outcomes) - {outcomes[i] for i in np.unique(y)})
        raise ConfigError(f"dataset: the training records have no {' and no '.join(missing)} outcome; "
                          f"the learner of {', '.join(outcomes)} needs every one")
    model = HistGradientBoostingClassifier(
        loss="log_loss", max_iter=0, learning_rate=config.learning_rate,
        max_leaf_nodes=config.max_leaf_nodes, min_samples_leaf=config.min_samples_leaf,
        l2_regularization=config.l2_regularization, early_stopping=False, random_state=seed, warm_start=True)
    losses: list[float] = []
    while model.max_iter < config.max_iter:
        model.max_iter = min(model.max_iter + BOOST_CHUNK, config.max_iter)
        model.fit(X, y)
        staged = list(model.staged_predict_proba(Xv))[len(losses):]
        losses += [float(-np.mean(np.log(np.clip(p[np.arange(len(yv)), yv], 1e-12, 1.0)))) for p in staged]
        if len(losses) - (int(np.argmin(losses)) + 1) >= config.patience:
            break
    best = int(np.argmin(losses)) + 1
    return Trees.from_sklearn(model, best), best, losses[best - 1]


@dataclasses.dataclass
class BoostedTrainingResult:
    members: list  # [Trees]
    card: dict
    plan_members: list = dataclasses.field(default_factory=list)  # [Trees], binary


# The plan learner's two classes, in its label order (blc_success False, True).
PLAN_OUTCOMES = ("no_plan", "planned")
# Offset of the plan learners' seeds and bootstrap generator from the outcome learners'.
PLAN_SEED_OFFSET = 7919


def _without_switches(arrays: dict) -> dict:
    keep = np.asarray(arrays["kind"]).astype(str) != "switch"
    return {key: (np.asarray(v)[keep] if np.ndim(v) and len(v) == len(keep) else v) for key, v in arrays.items()}


def _bootstrap_rows(rng, ids: np.ndarray, scene: np.ndarray) -> np.ndarray:
    """The rows of a bootstrap of whole scenes (``ids`` drawn with replacement)."""
    drawn = rng.choice(ids, size=len(ids), replace=True)
    by_scene = {s: np.flatnonzero(scene == s) for s in np.unique(drawn)}
    return np.concatenate([by_scene[s] for s in drawn]) if len(drawn) else np.zeros(0, np.int64)


def plan_split(split: dict, plan_scene, fractions, seed: int) -> dict:
    """The plan dataset's scenes in the outcome learners' split: a scene of both datasets (the
    same seed and index) in its split, so that no test scene's chains are learned; the plan
    dataset's other scenes split by ``fractions`` on their own."""
    from qz_drake.capability.training import split_scenes

    ids = np.unique(np.asarray(plan_scene, dtype=np.int64))
    known = np.concatenate(list(split.values()))
    extra = ids[~np.isin(ids, known)]
    own = split_scenes(extra, fractions, seed) if len(extra) >= 3 else {"train": extra}
    return {name: np.sort(np.concatenate([ids[np.isin(ids, split[name])], own.get(name, np.zeros(0, np.int64))]))
            for name in split}


def train_boosted(arrays: dict, *, fingerprint: str, fingerprints: dict | None = None,
                  config: BoostedConfig | None = None, progress: bool = False,
                  plan_arrays: dict | None = None, plan_source: dict | None = None) -> BoostedTrainingResult:
    """Trains the boosted capability model on a dataset's arrays (one row per executed trial;
    topology switches are left out, as for the networks) and scores it on the test scenes.

    ``plan_arrays`` (dataset.load_plan_arrays: missions labelled by the BLC alone, the plan
    chains') adds a binary plan learner beside each outcome learner, trained on whether the BLC
    planned, from the executed records and the chains' records: the model's no-plan is then
    the plan learner's, and walked and failed share the rest as the outcome learner shares
    them (``with_plan``). The outcome learners are those trained without it (the same
    bootstraps and seeds). The chains' scenes follow the outcome learners' split
    (``plan_split``); the card's ``test_plan`` scores no plan on the chains' test scenes with
    and without the plan learners. ``plan_source``: what the card says of where the chains'
    records came from (their dataset's path and fingerprint)."""
    from qz_drake.capability.dataset import check_arrays
    from qz_drake.capability.training import ENSEMBLE_SEED_STEP, split_scenes
    from qz_drake.progress import ProgressReport

    config = (config or BoostedConfig()).check()
    if not isinstance(fingerprint, str) or not fingerprint:
        raise bad_value("dataset.manifest.fingerprint", fingerprint, "expected a non-empty string")
    check_arrays(arrays)
    arrays = _without_switches(arrays)
    split = split_scenes(arrays["scene"], config.split, config.seed)
    scene = np.asarray(arrays["scene"], dtype=np.int64)
    rows = {name: np.flatnonzero(np.isin(scene, ids)) for name, ids in split.items()}
    Xv, validation_source = record_inputs(arrays, rows["validation"])
    yv = record_labels(arrays, validation_source)
    rng = np.random.default_rng(config.seed)
    planning = plan_arrays is not None
    if planning:
        plan_arrays = _without_switches(plan_arrays)
        plan_scene = np.asarray(plan_arrays["scene"], dtype=np.int64)
        psplit = plan_split(split, plan_scene, config.split, config.seed)
        prows = {name: np.flatnonzero(np.isin(plan_scene, ids)) for name, ids in psplit.items()}
        chains = record_features(plan_arrays, prows["validation"], labels="plan")
        Xpv = np.concatenate([Xv, chains[0]])
        ypv = np.concatenate([record_labels(arrays, validation_source, "plan"), chains[1]])
        if len(ypv) == 0:
            raise bad_value("plan_dataset", "no validation scenes", "the plan learner needs validation records")
        plan_rng = np.random.default_rng(config.seed + PLAN_SEED_OFFSET)
    members, info, plan_members, plan_info = [], [], [], []
    start = time.perf_counter()
    with ProgressReport("training boosted learners", config.members * (2 if planning else 1), unit="learners",
                        enabled=progress) as report:
        for m in range(config.members):
            if config.members == 1:
                train_rows = rows["train"]
            else:  # a bootstrap of whole training scenes
                train_rows = _bootstrap_rows(rng, split["train"], scene)
            X, source = record_inputs(arrays, train_rows, mirror=config.mirror)
            y = record_labels(arrays, source)
            trees, best, loss = _fit_member(X, y, Xv, yv, config, config.seed + ENSEMBLE_SEED_STEP * m)
            members.append(trees)
            info.append({"iterations": best, "validation_log_loss": loss, "train_rows": int(len(y))})
            report.update(advance=1, status=f"learner {m + 1}: {best} iterations")
            if not planning:
                continue
            chain_rows = (prows["train"] if config.members == 1
                          else _bootstrap_rows(plan_rng, psplit["train"], plan_scene))
            # The executed rows' features as the outcome learner had them, with the plan label.
            chains = record_features(plan_arrays, chain_rows, mirror=config.mirror, labels="plan")
            X = np.concatenate([X, chains[0]])
            y = np.concatenate([record_labels(arrays, source, "plan"), chains[1]])
            trees, best, loss = _fit_member(X, y, Xpv, ypv, config,
                                            config.seed + PLAN_SEED_OFFSET + ENSEMBLE_SEED_STEP * m, PLAN_OUTCOMES)
            plan_members.append(trees)
            plan_info.append({"iterations": best, "validation_log_loss": loss, "train_rows": int(len(y)),
                              "chain_rows": int(len(chains[1]))})
            report.update(advance=1, status=f"plan learner {m + 1}: {best} iterations")
    model = BoostedCapabilityModel(members, {"fingerprint": fingerprint}, plan_members=plan_members)
    card = {"learner": LEARNER, "fingerprint": fingerprint, "fingerprints": dict(fingerprints or {}),
            "config": dataclasses.asdict(config), "split": {k: v.tolist() for k, v in split.items()},
            "features": list(FEATURE_NAMES), "outcomes": list(OUTCOMES), "members": info,
            "train_seconds": time.perf_counter() - start,
            "n": {name: int(len(r)) for name, r in rows.items()}}
    card["test"] = test_scores(model, arrays, rows)
    card["cards"] = network_cards(arrays, rows)
    if planning:
        alone = BoostedCapabilityModel(members, {"fingerprint": fingerprint})
        card["plan_learner"] = {"members": plan_info, "source": dict(plan_source or {}),
                                "split": {k: v.tolist() for k, v in psplit.items()},
                                "n": {name: int(len(r)) for name, r in prows.items()}}
        card["test_plan"] = {"with_plan_learners": plan_test_scores(model, plan_arrays, prows["test"]),
                             "outcome_learners_alone": plan_test_scores(alone, plan_arrays, prows["test"]),
                             "executed_outcome_learners_alone": test_scores(alone, arrays, rows)}
    return BoostedTrainingResult(members, card, plan_members)


def plan_test_scores(model, plan_arrays: dict, test: np.ndarray, bins: int = 10) -> dict:
    """How the model's no-plan ranks and is calibrated on the test rows of missions labelled by
    the BLC alone (AUC, Brier, ECE of P(no plan) against the BLC's refusals)."""
    from qz_drake.capability.evaluation import binary_metrics

    if len(test) == 0:
        return {}
    X, planned = record_features(plan_arrays, test, labels="plan")
    no_plan = model.outcomes_of_features(X)[:, 1]
    return {"n": int(len(planned)), "refused": int(np.sum(planned == 0)),
            "no_plan": binary_metrics(planned == 0, no_plan, bins=bins)}


def network_cards(arrays: dict, rows: dict) -> dict:
    """Per (topology, kind) of the data: the training rows' counts and failures (what
    CapabilityModel.plan_failure_share reads)."""
    from qz_drake.capability.training import _failure_counts, network_name

    topology, kind = np.asarray(arrays["topology"]).astype(str), np.asarray(arrays["kind"]).astype(str)
    out = {}
    for t in TOPOLOGY_NAMES:
        for k in P.KINDS:
            train = rows["train"][(topology[rows["train"]] == t) & (kind[rows["train"]] == k)]
            if len(train):
                out[network_name(t, k)] = {"topology": t, "kind": k, "n": {"train": int(len(train))},
                                           "failures": _failure_counts(arrays, train)}
    return out


def test_scores(model, arrays: dict, rows: dict, bins: int = 10) -> dict:
    """The model on the test rows: the three outcomes' Brier score and log loss against the
    training rows' frequencies, and each outcome ranked (ROC AUC) and calibrated (ECE), overall
    and per (topology, kind)."""
    from qz_drake.capability.evaluation import binary_metrics
    from qz_drake.capability.training import network_name, outcome_classes, outcome_scores

    test = rows["test"]
    if len(test) == 0:
        return {}
    X, y = record_features(arrays, test)
    probs = model.outcomes_of_features(X)
    prior_y = outcome_classes(np.asarray(arrays["success"])[rows["train"]],
                              np.asarray(arrays["blc_success"])[rows["train"]])
    prior = (np.bincount(prior_y, minlength=3) + 0.5) / (len(prior_y) + 1.5)

    def scores(p, labels):
        out = {"n": int(len(labels)), "counts": {o: int(np.sum(labels == i)) for i, o in enumerate(OUTCOMES)},
               "model": outcome_scores(p, labels),
               "base_rate": outcome_scores(np.broadcast_to(prior, p.shape), labels)}
        for i, o in enumerate(OUTCOMES):
            out[o] = binary_metrics(labels == i, p[:, i], bins=bins)
        return out

    result = {"all": scores(probs, y), "networks": {}}
    topology = np.asarray(arrays["topology"]).astype(str)[test]
    kind = np.asarray(arrays["kind"]).astype(str)[test]
    for t in TOPOLOGY_NAMES:
        for k in P.KINDS:
            m = (topology == t) & (kind == k)
            if m.any():
                result["networks"][network_name(t, k)] = scores(probs[m], y[m])
    return result


# -- the model -----------------------------------------------------------------------------------
class BoostedCapabilityModel(CapabilityModelBase):
    """The capability of every topology and kind from one boosted ensemble; answers what
    CapabilityModel answers (``success``, ``success_all``, ``map_success``,
    ``plan_failure_share``; and ``outcomes``), and loads from a folder whose ``model.json`` says
    ``"learner": "boosted"`` (CapabilityModel.load dispatches here). It runs on the CPU (no
    torch): ``QZ_TORCH_DEVICE`` does not apply, and an explicit other device is refused."""

    # Each query's answer is its own (no batch statistics): predict_map may take a map in bands.
    queries_independent = True

    def __init__(self, members: list, card: dict, device: str | None = None, plan_members: list | None = None):
        if not members:
            raise ConfigError("a boosted capability model needs at least one learner")
        self._members = list(members)
        # Binary learners of whether the BLC plans, one beside each outcome learner (trained on
        # the plan chains' labels too: train_boosted's plan_arrays); none: the outcome learners'
        # own no-plan.
        self._plan_members = list(plan_members or [])
        if self._plan_members and len(self._plan_members) != len(self._members):
            raise ConfigError(f"a boosted capability model needs a plan learner beside each of its "
                              f"{len(self._members)} learners, not {len(self._plan_members)}")
        if any(int(t.roots.shape[1]) != 1 for t in self._plan_members):
            raise ConfigError("a boosted capability model's plan learners are binary (one score a tree)")
        self.card = dict(card)
        self.device = "cpu"
        covered = self.card.get("cards")
        keys = ([tuple(name.split("/")) for name in covered] if covered
                else [(t, k) for t in TOPOLOGY_NAMES for k in P.KINDS])
        self._networks = {key: None for key in keys}
        if device not in (None, "cpu"):
            raise bad_value("device", device, "the boosted capability model runs on the CPU")

    def to(self, device: str) -> "BoostedCapabilityModel":
        if device != "cpu":
            raise bad_value("device", device, "the boosted capability model runs on the CPU")
        return self

    @classmethod
    def load_folder(cls, folder: Path, top: dict, device: str | None = None) -> "BoostedCapabilityModel":
        weights = folder / top.get("weights", WEIGHTS_FILE)
        if not weights.is_file():
            raise _error("model.weights", str(weights), "missing")
        if top.get("weights_sha256") != _sha256(weights):
            raise _error("model.weights", str(weights), "its SHA-256 differs from the card's (changed or foreign)")
        with np.load(weights, allow_pickle=False) as data:
            count = int(top.get("members_count", 0))
            if count < 1:
                raise _error("model.members_count", top.get("members_count"), "expected a positive count")
            members = [Trees.from_arrays(data, f"m{m}_") for m in range(count)]
            plans = int(top.get("plan_members_count", 0))
            if plans not in (0, count):
                raise _error("model.plan_members_count", plans, f"expected 0 or {count} (one beside each learner)")
            plan_members = [Trees.from_arrays(data, f"p{m}_") for m in range(plans)]
        if list(top.get("features", [])) != list(FEATURE_NAMES):
            raise _error("model.features", top.get("features"), "this code computes other features")
        return cls(members, top, device=device, plan_members=plan_members)

    @property
    def identity(self) -> str:
        digest = self.card.get("weights_sha256")
        return digest[:16] if digest else self.fingerprint

    @property
    def members(self) -> list:
        return list(self._members)

    @property
    def plan_members(self) -> list:
        """The plan learners beside the members (empty: the members' own no-plan)."""
        return list(self._plan_members)

    @property
    def scorer(self) -> "ForestScorer | None":
        """Every member's trees as one ForestScorer (built on first use), None where a tree
        has more leaves than it takes (then each member's trees are walked node by node)."""
        if not hasattr(self, "_scorer"):
            self._scorer = ForestScorer.of(self._members)
        return self._scorer

    @property
    def plan_scorer(self) -> "ForestScorer | None":
        """The plan learners' ForestScorer (as ``scorer``); None without plan learners."""
        if not hasattr(self, "_plan_scorer"):
            self._plan_scorer = ForestScorer.of(self._plan_members) if self._plan_members else None
        return self._plan_scorer

    def network(self, topology: str, kind: str):
        """(topology, kind) if the model covers it; the model's error naming it otherwise."""
        P.check_kind(kind)
        if (topology, kind) not in self._networks:
            raise _error("model.networks", f"{topology}/{kind}", "this model has no data for it")
        return (topology, kind)

    # -- inference ---------------------------------------------------------------------------
    def member_outcomes(self, X: np.ndarray) -> np.ndarray:
        """(members, n, 3) outcome probabilities of every learner; each distinct row of X is
        evaluated once (a map's flat ground repeats one query from cell to cell)."""
        X = np.asarray(X, dtype=np.float64)
        first, inverse = distinct_rows(X)
        unique = np.ascontiguousarray(X[first])
        scorer, plan_scorer = self.scorer, self.plan_scorer

        def rows(part):
            if scorer is not None:
                outcomes = scorer.probabilities(part)
            else:
                outcomes = np.stack([m.probabilities(part) for m in self._members])
            if not self._plan_members:
                return outcomes
            raw = (plan_scorer.raw(part) if plan_scorer is not None
                   else np.stack([m.raw(part) for m in self._plan_members]))
            return with_plan(outcomes, sigmoid(raw[..., 0]))

        return _over_free_cores(rows, unique, len(unique), axis=1)[:, inverse]

    def _grouped_outcomes(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(members, distinct groups, V, 3) outcomes of (n, V, features) rows whose first
        SHARED_FEATURES columns are the same along V (a patch in every topology and direction),
        and each group's index in them. Groups are compared whole (a flat world's cells repeat
        one); the scorer takes each group's patch columns once; over the free cores."""
        n, V, width = rows.shape
        wide = np.concatenate([rows[:, 0, :SHARED_FEATURES], rows[:, :, SHARED_FEATURES:].reshape(n, -1)], axis=1)
        first, inverse = distinct_rows(wide)
        unique = rows[first]
        scorer, plan_scorer = self.scorer, self.plan_scorer

        def groups(part):
            shared, variants = part[:, 0, :SHARED_FEATURES], part[:, :, SHARED_FEATURES:]
            if scorer is not None:
                outcomes = softmax(scorer.raw_grouped(shared, variants))
            else:
                flat = part.reshape(-1, width)
                outcomes = np.stack([m.probabilities(flat) for m in self._members]).reshape(-1, len(part), V, 3)
            if not self._plan_members:
                return outcomes
            if plan_scorer is not None:
                raw = plan_scorer.raw_grouped(shared, variants)[..., 0]
            else:
                flat = part.reshape(-1, width)
                raw = np.stack([m.raw(flat)[:, 0] for m in self._plan_members]).reshape(-1, len(part), V)
            return with_plan(outcomes, sigmoid(raw))

        return _over_free_cores(groups, unique, len(unique) * V, axis=1), inverse

    def outcomes_of_features(self, X: np.ndarray) -> np.ndarray:
        return self.member_outcomes(X).mean(axis=0)

    def outcomes(self, patches, feet, kind: str, topology: str, direction=None) -> np.ndarray:
        """(..., 3) P(walked), P(no plan), P(executed and failed) of queries shaped as for
        ``success``."""

        self.network(topology, kind)
        patches, batch = check_patches(patches)
        feet = np.asarray(feet, dtype=np.float32)
        if feet.shape != batch + (6, 3):
            raise _error("feet", f"array of shape {feet.shape}", f"expected {batch + (6, 3)} to match the patches")
        n = int(np.prod(batch, dtype=np.int64))
        d = check_direction(kind, direction, batch)
        X = features(patches.reshape(n, P.PATCH_SIZE, P.PATCH_SIZE), feet.reshape(n, 6, 3), kind, topology,
                     None if d is None else d.reshape(n))
        return self.outcomes_of_features(X).reshape(batch + (3,))

    def success(self, patches, feet, kind: str, topology: str, direction=None) -> np.ndarray:
        """P(walked) of queries: (..., 20, 20) patches, (..., 6, 3) feet, d for turns."""
        return self.outcomes(patches, feet, kind, topology, direction)[..., 0]

    def success_all(self, patches, feet: dict, kind: str) -> dict:
        """topology -> (success, plan, spread) as CapabilityModel.success_all: every topology
        on the same patches with its own feet; turns (2, ...) left, right."""

        P.check_kind(kind)
        patches, batch = check_patches(patches)
        n = int(np.prod(batch, dtype=np.int64))
        flat = patches.reshape(n, P.PATCH_SIZE, P.PATCH_SIZE)
        directions = (P.TURN_LEFT, P.TURN_RIGHT) if kind == "turn" else (None,)
        shape = (len(directions),) + batch if kind == "turn" else batch
        checked = {}
        for t, f in feet.items():
            self.network(t, kind)
            f = np.asarray(f, dtype=np.float32)
            if f.shape != batch + (6, 3):
                raise _error(f"feet[{t}]", f"array of shape {f.shape}", f"expected {batch + (6, 3)} to match the patches")
            checked[t] = f.reshape(n, 6, 3)
        if not checked:
            return {}
        spread = len(self._members) > 1
        out = {t: [np.empty((len(directions), n)), np.empty((len(directions), n)),
                   np.empty((len(directions), n)) if spread else None] for t in checked}
        # A map's queries a chunk of patches at a time (each query's answer is its own, so the
        # numbers do not depend on the chunks): a 100 m map's features would be a gigabyte.
        for a in range(0, n, MAP_CHUNK):
            b = min(a + MAP_CHUNK, n)
            part = _over_free_cores(patch_features, flat[a:b], b - a)  # the same patches for every topology
            # (patches, variants, features): every topology's and direction's query of a patch.
            rows = np.stack([features(flat[a:b], f[a:b], kind, t, d, patch_part=part)
                             for t, f in checked.items() for d in directions], axis=1)
            probs, inverse = self._grouped_outcomes(rows)  # (members, distinct patches, variants, 3)
            walked = probs[..., 0]
            summary = [walked.mean(axis=0), (1.0 - probs[..., 1]).mean(axis=0), walked.std(axis=0) if spread else None]
            for i, t in enumerate(checked):
                for target, value in zip(out[t], summary):
                    if target is not None:
                        target[:, a:b] = value[inverse, i * len(directions):(i + 1) * len(directions)].T
        return {t: tuple(None if v is None else v.reshape(shape) for v in values) for t, values in out.items()}


def save_boosted(result: BoostedTrainingResult, out_dir) -> Path:
    """Writes ``boosted.npz`` (the learners' arrays, no pickle) and ``model.json`` (the card,
    with the weights' SHA-256); returns the folder."""

    folder = Path(out_dir)
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for m, trees in enumerate(result.members):
        arrays.update(trees.arrays(f"m{m}_"))
    for m, trees in enumerate(result.plan_members):
        arrays.update(trees.arrays(f"p{m}_"))
    def write(path):
        with open(path, "wb") as f:  # a file object: numpy would add ".npz" to the aside name
            np.savez_compressed(f, **arrays)

    _replace(folder / WEIGHTS_FILE, write)
    card = dict(result.card, format=MODEL_FORMAT, version=FORMAT_VERSION, weights=WEIGHTS_FILE,
                members_count=len(result.members), weights_sha256=_sha256(folder / WEIGHTS_FILE),
                **({"plan_members_count": len(result.plan_members)} if result.plan_members else {}))
    text = json.dumps(card, indent=1, sort_keys=True, default=_plain) + "\n"
    _replace(folder / MODEL_CARD, lambda path: Path(path).write_text(text))
    return folder


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if dataclasses.is_dataclass(value):
        return dataclasses.asdict(value)
    raise TypeError(type(value).__name__)
