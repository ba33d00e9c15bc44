"""``qz demo``: the main job on the embedded default world.

Qingzhui walks a route across the packaged grid_map test field (real heightmap, hydroelastic
mesh) in 1 m missions, each planned by the BLC's trajectory optimisation from the measured
state and tracked by IK + joint PD; then it stands in front of the BLC paper's stairs scene.
Each run writes a meshcat recording, plots and metrics; the demo writes a picture of the world
with the walked path and a summary.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from qz_drake.config import ControllerConfig, Scenario, SimulationConfig, TerrainConfig, Waypoint
from qz_drake.errors import bad_value
from qz_drake.simulation import simulate


def demo_scenarios() -> tuple[Scenario, ...]:
    # The route ends on the corridor's centreline: 0.3 m to the right of it, the bent-out RF
    # shank met the 0.35 m wall at y = -0.85 m (a leg contact the verdict fails).
    walk = Scenario(
        name="walk_grid_map", description="Walk 4 m across the grid_map test field.",
        terrain=TerrainConfig(kind="grid_map", contact="mesh"),
        simulation=SimulationConfig(duration=30.0),
        controller=ControllerConfig(kind="walk", planner="blc",
                                    route=[Waypoint(x=3.0), Waypoint(x=4.0, y=0.0, yaw=-0.3)]))
    stand = Scenario(
        name="stand_stairs", description="Standing before two 0.1 m stairs, front knees in.",
        terrain=TerrainConfig(kind="stairs", params={"rise": 0.1, "run": 0.4, "count": 2, "start_x": 0.5}))
    stand.robot.topology = "front_bend"
    return walk, stand


def run_demo(out_dir: str | Path, duration: float | None = None) -> dict:
    from qz_drake.station import make_heightmap
    from qz_drake.viz.plots import plot_heightmap

    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise bad_value("duration", duration, "must be a finite positive number of seconds")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs, paths = {}, {}
    scenarios = demo_scenarios()
    for scenario in scenarios:
        if duration is not None:
            scenario.simulation.duration = duration
        result = simulate(scenario, out_dir=out / scenario.name)
        runs[scenario.name] = result.metrics
        paths[scenario.name] = result.states[:, 4:6]
    headline = scenarios[0]
    world = make_heightmap(headline.terrain)
    plot_heightmap(world.crop(-3.0, 7.0, -3.0, 3.0), out / "world.png",
                   title="default world (grid_map test field): walked path", start_xy=(0.0, 0.0),
                   path_xy=np.asarray(paths[headline.name]))
    (out / "recording.html").write_text((out / headline.name / "recording.html").read_text())
    summary = {"success": all(m["success"] for m in runs.values()), "runs": runs,
               "recording": str(out / "recording.html"), "picture": str(out / "world.png")}
    (out / "metrics.json").write_text(json.dumps(summary, indent=2))
    return summary
