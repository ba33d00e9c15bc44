"""Simulation speed: real-time factor of Qingzhui standing (joint PD, Eq. 7).

Cases: flat ground as one box with point contact; the grid_map heightmap (0.05 m cells, 0-0.4 m)
as a rigid hydroelastic mesh with compliant hydroelastic feet. Median of `repeats` runs.
"""

import statistics

from qz_drake.config import Scenario, SimulationConfig, TerrainConfig
from qz_drake.simulation import simulate

CASES = {
    "flat_boxes": TerrainConfig(kind="flat", contact="boxes"),
    "grid_map_mesh": TerrainConfig(kind="grid_map", contact="mesh"),
}


def run(repeats: int = 3, quick: bool = False, duration: float = 5.0) -> dict:
    if quick:
        repeats, duration = 1, 1.0
    out = {}
    for name, terrain in CASES.items():
        scenario = Scenario(name=name, terrain=terrain, simulation=SimulationConfig(duration=duration))
        factors, ok = [], []
        for _ in range(repeats):
            result = simulate(scenario)
            factors.append(result.metrics["realtime_factor"])
            ok.append(result.metrics["success"])
        out[name] = {"realtime_factor_median": statistics.median(factors),
                     "realtime_factors": factors, "sim_time_s": duration,
                     "standing_success": all(ok)}
    return out
