"""``qz demo``: the main job on the embedded default world.

For now (until walking lands): Qingzhui stands on the packaged grid_map heightmap and on the
BLC paper's stairs scene; each run writes a meshcat recording, a plot and metrics, and the
demo writes a picture of the world and a summary metrics.json.
"""

from __future__ import annotations

import json
from pathlib import Path

from qz_drake.config import Scenario, SimulationConfig, TerrainConfig
from qz_drake.simulation import simulate

DEMO_SCENARIOS = (
    Scenario(name="stand_grid_map", description="Standing on the grid_map test field.",
             terrain=TerrainConfig(kind="grid_map", contact="mesh")),
    Scenario(name="stand_stairs", description="Standing in front of two 0.1 m stairs.",
             terrain=TerrainConfig(kind="stairs", params={"rise": 0.1, "run": 0.4, "count": 2,
                                                          "start_x": 0.5})),
)


def run_demo(out_dir: str | Path, duration: float | None = None) -> dict:
    from qz_drake.station import make_heightmap
    from qz_drake.viz.plots import plot_heightmap

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = {}
    for scenario in DEMO_SCENARIOS:
        if duration is not None:
            scenario.simulation = SimulationConfig(duration=duration)
        result = simulate(scenario, out_dir=out / scenario.name)
        runs[scenario.name] = result.metrics
    world = make_heightmap(DEMO_SCENARIOS[0].terrain)
    plot_heightmap(world, out / "world.png", title="default world: grid_map test field",
                   start_xy=(0.0, 0.0))
    # The first run's recording is the demo's headline recording.
    (out / "recording.html").write_text((out / DEMO_SCENARIOS[0].name / "recording.html").read_text())
    summary = {"success": all(m["success"] for m in runs.values()), "runs": runs,
               "recording": str(out / "recording.html"), "picture": str(out / "world.png")}
    (out / "metrics.json").write_text(json.dumps(summary, indent=2))
    return summary
