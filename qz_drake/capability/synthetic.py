"""A synthetic trial dataset with a known answer, for tests and benchmarks of the networks.

The arrays have the keys and dtypes of ``qz_drake.capability.dataset.load_training_arrays``
(one row per executed trial). Each scene is a step across the patch at a random distance
ahead of the robot and of a random height (plus a little roughness); the label is a known
function of the patch: a trial succeeds when the patch's height range is at most
``max_step`` (0.15 m by default), and a fraction ``label_noise`` of the labels is flipped.
A failure is the BLC's (no plan) unless its range is within ``failure_band`` above
``max_step``: those are executed and fail (the three outcomes of issue 37).
Nothing here is a simulation: it checks that the learning machinery can learn a rule that
is in the data.
"""

from __future__ import annotations

import numpy as np

from qz_drake.capability.patches import KINDS, MOVE_PATCH_SPACING, PATCH_SIZE, TURN_PATCH_SPACING

# Largest step the synthetic robot climbs. [m]
SYNTHETIC_MAX_STEP = 0.15


def synthetic_rule(patches, max_step: float = SYNTHETIC_MAX_STEP) -> np.ndarray:
    """The synthetic label before noise: success when the patch's height range <= max_step."""
    patches = np.asarray(patches)
    return (patches.max(axis=(-2, -1)) - patches.min(axis=(-2, -1))) <= max_step


def synthetic_arrays(*, scenes: int = 40, headings: int = 12, topologies=("nominal",), kinds=KINDS,
                     max_step: float = SYNTHETIC_MAX_STEP, label_noise: float = 0.03,
                     failure_band: float = 0.0, seed: int = 0) -> tuple[dict[str, np.ndarray], dict]:
    """(arrays, manifest) in the dataset contract: ``scenes * headings`` rows per (topology, kind).

    Args:
        scenes: scene ids 0..scenes-1; each scene fixes a step height (uniform 0-0.3 m).
        headings: trials per scene and network (a heading each: the step's distance ahead
            and its angle vary with it).
        topologies, kinds: the networks that get rows.
        max_step: the rule's threshold. [m]
        label_noise: fraction of labels flipped.
        failure_band: failures whose height range is at most max_step + failure_band are
            executed and fail (blc_success True); the others are not planned. [m]
        seed: everything is drawn from it.
    """
    rng = np.random.default_rng(seed)
    step = rng.uniform(0.0, 0.3, scenes)
    rows: dict[str, list] = {k: [] for k in ("patch", "feet", "direction", "success", "blc_success",
                                             "scene", "scene_kind", "topology", "kind")}
    offsets = np.arange(PATCH_SIZE) - (PATCH_SIZE - 1) / 2.0
    for topology in topologies:
        for kind in kinds:
            spacing = TURN_PATCH_SPACING if kind == "turn" else MOVE_PATCH_SPACING
            n = scenes * headings
            scene = np.repeat(np.arange(scenes), headings)
            u = offsets[None, :, None] * spacing
            v = offsets[None, None, :] * spacing
            angle = rng.uniform(-0.4, 0.4, n)[:, None, None]
            edge = rng.uniform(-0.6, 0.8, n)[:, None, None] * (PATCH_SIZE * spacing / 2)
            # A step rising ahead; its edge crosses the patch at an angle, or lies past it.
            ahead = (np.cos(angle) * u + np.sin(angle) * v) > edge
            height = step[scene][:, None, None] * rng.uniform(0.9, 1.1, n)[:, None, None]
            patch = np.where(ahead, height, 0.0) + rng.normal(0.0, 0.005, (n, PATCH_SIZE, PATCH_SIZE))
            patch = patch.astype(np.float32)
            label = synthetic_rule(patch, max_step)
            flip = rng.random(n) < label_noise
            feet = rng.normal(0.0, 0.02, (n, 6, 3)) + np.array(
                [[0.6, 0.0, 0.0], [0.3, -0.5, 0.0], [-0.3, -0.5, 0.0],
                 [-0.6, 0.0, 0.0], [-0.3, 0.5, 0.0], [0.3, 0.5, 0.0]])
            rows["patch"].append(patch)
            rows["feet"].append(feet.astype(np.float32))
            rows["direction"].append(rng.integers(0, 2, n).astype(np.int8) if kind == "turn"
                                     else np.full(n, -1, np.int8))
            rows["success"].append(label ^ flip)
            steps = patch.max(axis=(-2, -1)) - patch.min(axis=(-2, -1))
            rows["blc_success"].append(label | flip | (steps <= max_step + failure_band))
            rows["scene"].append(scene.astype(np.int64))
            rows["scene_kind"].append(np.full(n, "step"))
            rows["topology"].append(np.full(n, topology))
            rows["kind"].append(np.full(n, kind))
    arrays = {k: np.concatenate(v) for k, v in rows.items()}
    # No robot fingerprint: the labels describe no robot configuration, so CapabilityModel.load's
    # robot check lets a model trained on them through.
    fingerprints = {"blc": "synthetic-blc", "controller": "synthetic-controller",
                    "verdict": f"synthetic-range<={max_step}"}
    manifest = {"fingerprint": f"synthetic-{seed}-{max_step}", "fingerprints": fingerprints,
                "synthetic": True, "topologies": list(topologies), "kinds": list(kinds)}
    return arrays, manifest

