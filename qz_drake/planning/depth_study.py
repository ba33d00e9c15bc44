"""Success rate of the static-gait search against its depth (paper 003 section 4.2, Fig. 10).

The paper shows one terrain where looking one step ahead runs into a collision that looking four
steps ahead avoids. We measure the claim: on ``terrains`` seeded cuboid terrains (cuboids of
random heights, edges invalid; :func:`~qz_drake.planning.static_gait.cuboid_terrain`) the
search walks ``steps`` swings at each depth, and a depth's success rate is the share of terrains
on which it found all of them. Terrain k uses seed ``seed + k``, so a study is reproducible and
two studies with the same seed see the same terrains.

The study's candidates (``DEPTH_STUDY_GAIT``) are section 4.2's: footholds ordered by distance
to the default one, and three body heights (h0, h0 + dh, h0 - dh); no roll or pitch offsets.
What we measured with other settings (benchmarks/BENCHMARKS.md): adding roll and pitch offsets
gives the greedy search enough ways out that on 0.025 m cuboids every depth succeeds on every
terrain, and on 0.05 m cuboids most terrains have a step no depth can take.
"""

import dataclasses
import time

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.planning.static_gait import StaticGaitConfig, cuboid_terrain, search_gait


DEPTH_STUDY_GAIT = StaticGaitConfig(height_count=3, pitch_count=1, roll_count=1, max_nodes=2000)
"""Search settings of the depth study: footholds and three body heights (section 4.2)."""
# Most terrains one study may search: 20 times Fig. 10's 50 (a terrain takes seconds per depth).
MAX_TERRAINS = 1000


@dataclasses.dataclass
class DepthStudy:
    depths: list[int]
    terrains: int
    steps: int
    # Largest cuboid height. [m]
    max_height: float
    seed: int
    # Depth -> share of terrains where the search found all steps.
    success_rate: dict[int, float]
    # (terrains, depths): found all steps; steps found; candidate states checked; search time [s].
    success: np.ndarray
    states: np.ndarray
    nodes: np.ndarray
    time_s: np.ndarray
    # Depth -> {failed check that ended the search: count} over the failed terrains.
    failure_causes: dict[int, dict[str, int]]
    config: StaticGaitConfig

    def to_dict(self) -> dict:
        return {
            "depths": self.depths, "terrains": self.terrains, "steps": self.steps, "max_height_m": self.max_height,
            "seed": self.seed, "success_rate": {str(d): r for d, r in self.success_rate.items()},
            "mean_states": {str(d): float(self.states[:, k].mean()) for k, d in enumerate(self.depths)},
            "median_time_s": {str(d): float(np.median(self.time_s[:, k])) for k, d in enumerate(self.depths)},
            "median_nodes": {str(d): float(np.median(self.nodes[:, k])) for k, d in enumerate(self.depths)},
            "failure_causes": {str(d): c for d, c in self.failure_causes.items()},
            "depth_beats_greedy": [int(t) for t in np.flatnonzero(self.success[:, -1] & ~self.success[:, 0])],
        }


def _cause(reason: str) -> str:
    """'dead end at step 7 (LB): reach x20, body_rear x3' -> 'reach'."""
    tail = reason.split(": ", 1)[-1]
    return tail.split(",")[0].split(" x")[0].strip() or reason


def depth_study(depths=(1, 2, 3, 4), terrains: int = 50, *, steps: int = 12, max_height: float = 0.025,
                seed: int = 0, config: StaticGaitConfig | None = None, progress: bool = False) -> DepthStudy:
    """Runs the gait search at every depth on ``terrains`` cuboid terrains.

    Args:
        depths: search depths to compare, e.g. 1 (greedy) to 4.
        terrains: number of seeded terrains.
        steps: swings to find on each.
        max_height: cuboid heights are uniform in [0, max_height]. [m]
        seed: terrain k has seed ``seed + k``.
        config: the search's settings; default DEPTH_STUDY_GAIT.
        progress: show a progress bar.
    """
    depths = [int(d) for d in depths]
    if not depths or min(depths) < 1:
        raise bad_value("depths", depths, "must be one or more depths >= 1")
    if not 1 <= int(terrains) <= MAX_TERRAINS:
        raise bad_value("terrains", terrains, f"must be within [1, {MAX_TERRAINS}]")
    if int(steps) < 1:
        raise bad_value("steps", steps, "must be >= 1")
    if not (np.isfinite(max_height) and max_height >= 0):
        raise bad_value("max_height", max_height, "must be >= 0 metres")
    config = config or dataclasses.replace(DEPTH_STUDY_GAIT)
    shape = (int(terrains), len(depths))
    success = np.zeros(shape, dtype=bool)
    states, nodes, times = np.zeros(shape, dtype=int), np.zeros(shape, dtype=int), np.zeros(shape)
    causes: dict[int, dict[str, int]] = {d: {} for d in depths}
    rows = range(int(terrains))
    if progress:
        from rich.console import Console
        from rich.progress import track

        rows = track(rows, description="depth study (terrains)", console=Console(stderr=True), transient=True)
    for k in rows:
        terrain = cuboid_terrain(seed + k, max_height=max_height)
        for j, depth in enumerate(depths):
            start = time.perf_counter()
            result = search_gait(terrain, (0.0, 0.0), 0.0, steps=steps, depth=depth, config=config)
            times[k, j] = time.perf_counter() - start
            success[k, j], states[k, j], nodes[k, j] = result.success, len(result.states), result.nodes_expanded
            if not result.success:
                cause = _cause(result.reason)
                causes[depth][cause] = causes[depth].get(cause, 0) + 1
    rate = {d: float(success[:, j].mean()) for j, d in enumerate(depths)}
    return DepthStudy(depths, int(terrains), int(steps), float(max_height), int(seed), rate, success, states, nodes,
                      times, causes, config)
