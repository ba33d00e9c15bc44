"""``qz demo``: the main job, paper 000's whole CapPlanner on the composite long_range world.

Qingzhui stands at (0, 0) of the seeded 20 m x 20 m ``long_range`` world (stairs, slopes,
trenches, rough patches, boxes and pits on 4 m tiles) and is given a goal across it. The TLC
(the shipped capability model, value iteration over the map in the six topologies) plans the
route, splits it into BLC missions and topology switches and replans at every mission start;
each mission is solved by the BLC's trajectory optimisation from the expected state and
tracked by IK + joint PD in Drake, in one diagram. The demo writes the meshcat recording (the
guidance path drawn over the terrain), the utility map with the planned and walked paths
(paper 000 Fig. 6), plots and metrics.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from qz_drake.config import (ControllerConfig, Scenario, SimulationConfig, TerrainConfig, WalkDrives, Waypoint,
                             drive_station)
from qz_drake.errors import bad_value
from qz_drake.planning.capplanner_route import route_source_for
from qz_drake.simulation import simulate

# The demo's world and goal: long_range seed 0, from (0, 0) to the lane crossing at (14, 14),
# 19.8 m away on the straight line.
DEMO_SEED = 0
DEMO_GOAL = (14.0, 14.0)
# Where the robot stands at the start (the world's origin). [m]
DEMO_START = (0.0, 0.0)


# Goals 6-7 m from the demo's start, for a short walk (tests, notebook 04): see nearer_goal.
NEAR_GOALS = ((6.0, 6.0), (6.0, 3.0), (3.0, 6.0), (6.0, 0.0), (0.0, 6.0))


def nearer_goal(candidates=NEAR_GOALS, seed: int = DEMO_SEED, model=None) -> tuple[tuple[float, float], dict]:
    """(goal, {candidate: predicted chance of no fall}): of goals near the demo's start, the one
    whose route the capability model (default: the shipped one) is most confident about.

    A short walk that is to show the planner at work should follow a route the planner
    believes in: a test asserting the success of a route predicted at 0.66 is a coin toss
    (with the model of 12 264 trials, (6, 6)'s route crosses a move with a 28 % chance of a
    fall, and the walk failed there by a leg on the terrain)."""
    from qz_drake.capability.model import CapabilityModel, predict_map
    from qz_drake.planning.capability_mdp import CapabilityMdpConfig, plan_on_map, switchable_cells
    from qz_drake.scene import make_heightmap

    model = CapabilityModel.load() if model is None else model
    scenario = demo_scenario(seed=seed)
    heightmap = make_heightmap(scenario.terrain, seed=scenario.random_seed)
    start = DEMO_START
    config = CapabilityMdpConfig()
    capability_map = predict_map(model, heightmap, anchor=start)
    switchable = switchable_cells(heightmap, capability_map.xs, capability_map.ys, config)
    confidence = {}
    for goal in candidates:
        result = plan_on_map(capability_map, start, 0, goal, config=config, switchable=switchable)
        confidence[tuple(goal)] = result.fall_free_probability if result.reaches_goal else 0.0
    return max(confidence, key=confidence.get), confidence


def demo_scenario(goal=DEMO_GOAL, seed: int = DEMO_SEED) -> Scenario:
    """The CapPlanner walk of the demo (also scenarios/capplanner_long_range.yaml), its joints
    driven as the trials and Fig. 9's walks drive them (config.WalkDrives)."""
    controller = ControllerConfig(kind="walk", planner="capplanner",
                                  route=[Waypoint(x=float(goal[0]), y=float(goal[1]))])
    return Scenario(
        name="capplanner_long_range", random_seed=seed,
        description=f"CapPlanner across the long_range world from (0, 0) to ({goal[0]:g}, {goal[1]:g}).",
        terrain=TerrainConfig(kind="long_range"),
        simulation=SimulationConfig(duration=300.0, time_step=WalkDrives.time_step),
        station=drive_station(WalkDrives.control_mode, controller.kp, controller.kd),
        controller=controller)


def run_demo(out_dir: str | Path, duration: float | None = None, goal=DEMO_GOAL, *, progress: bool = False) -> dict:
    """Runs the demo walk into ``out_dir``; returns the summary (also written to summary.json;
    metrics.json holds every metric of the walk). ``progress``: on stderr, the planning, then
    the simulated time against the walk's expected end and the missions planned
    (qz_drake.progress)."""
    from qz_drake.progress import ProgressReport, simulation_progress

    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise bad_value("duration", duration, "must be a finite positive number of seconds")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scenario = demo_scenario(goal)
    if duration is not None:
        scenario.simulation.duration = duration
    with ProgressReport("demo: building the world and planning the route", unit="s simulated", digits=1,
                        enabled=progress) as report:
        result = simulate(scenario, out_dir=out, route_source=route_source_for(scenario),
                          progress=simulation_progress(report, "demo: walking"))
    keys = ("success", "reason", "reasons", "final_xy_error_m", "missions", "topology_changes", "replans",
            "tlc_recoveries", "planning_time_s", "value_iterations", "blc_solves", "blc_failures",
            "blc_retries", "blc_solve_time_s",
            "sim_time_s", "wall_time_s", "realtime_factor", "max_tilt_deg", "max_joint_error_deg",
            "max_foot_slip_m", "leg_terrain_contacts", "trunk_terrain_contacts", "unreachable")
    summary = {"scenario": scenario.name, "goal": list(goal),
               **{k: result.metrics[k] for k in keys if k in result.metrics},
               "files": {name: str(path) for name, path in result.files.items()}}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
