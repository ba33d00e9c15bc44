"""Plan with the learned capability model, then walk the plan in Drake (paper 000's CapPlanner).

First the top-level controller (TLC) alone, as ``qz plan`` runs it: the shipped capability
model predicts the success of every move over the map in one batch, value iteration over the
capability MDP (1 m cells x 8 headings x 6 topologies) gives the most likely path to the goal,
and ``split_missions`` cuts it into BLC missions. Then the whole CapPlanner in one Drake
diagram, as ``qz simulate`` runs a ``planner: capplanner`` scenario: the TLC as a LeafSystem
(CapabilityVIPlanner, replanning at each mission start) hands each local target to the BLC
(TrajectoryOptimizationBLC), whose plan the IK tracker and joint PD follow on the simulation
station; the walk is judged by the strict verdict.

Run (writes plan.png, then the walk's recording.html, plots and metrics.json, under --out):

    .venv/bin/python examples/plan_and_walk.py [--short] [--out DIR]

The default walks 4 m, over two stairs and on (about 20 s of wall time); ``--short`` ends on the
top stair, 2 m out.
"""

import argparse
import math
import sys
from pathlib import Path

from qz_drake.capability.model import CapabilityModel
from qz_drake.capability.plots import plot_plan
from qz_drake.config import ControllerConfig, Scenario, SimulationConfig, TerrainConfig, Waypoint
from qz_drake.planning.capability_mdp import plan
from qz_drake.planning.capplanner_route import route_source_for
from qz_drake.planning.guidance import split_missions
from qz_drake.scene import make_heightmap
from qz_drake.simulation import simulate


def plan_alone(scenario, out: Path):
    """The TLC alone on the scenario's map, from the start to the route's last waypoint."""
    heightmap = make_heightmap(scenario.terrain, scenario.random_seed)
    start, goal = tuple(scenario.robot.initial_xy), (scenario.controller.route[-1].x, scenario.controller.route[-1].y)
    heading = round(scenario.robot.initial_yaw / (math.pi / 4)) % 8  # the MDP's headings are 45 deg apart
    result = plan(CapabilityModel.load(), heightmap, start, heading, goal)
    if not result.reaches_goal:
        print(f"the TLC finds no path from {start} to {goal}")
        return False
    print(f"TLC: {len(result.steps)} actions to {goal}, predicted P(success) {result.success_probability:.2f}, "
          f"P(no fall) {result.fall_free_probability:.2f}; value iteration {result.solution.iterations} iterations")
    for k, mission in enumerate(split_missions(result.steps, start_yaw=scenario.robot.initial_yaw)):
        x, y, yaw = mission.target
        print(f"  mission {k}: to ({x:.1f}, {y:.1f}) heading {math.degrees(yaw):.0f} deg in {mission.topology}, "
              f"predicted success {mission.success:.2f}")
    print(f"plan: {plot_plan(heightmap, result, out / 'plan.png', title='the TLC on ' + scenario.name)}")
    return True


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--short", action="store_true", help="a 2 m walk instead of 4 m")
    parser.add_argument("--out", default="out/examples/plan_and_walk", help="output folder")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    # A 7 m x 4 m world from x = -2 m: two 0.1 m stairs up from x = 1.4 m, then level.
    stairs = {"rise": 0.1, "run": 0.5, "count": 2, "start_x": 1.4, "size_x": 7.0}
    goal = (2.0, 0.0) if args.short else (4.0, 0.0)
    scenario = Scenario(
        name="plan_and_walk", terrain=TerrainConfig(kind="stairs", params=stairs),
        # A time limit, not the walk's length: the walk ends when its last mission has.
        simulation=SimulationConfig(duration=60.0),
        controller=ControllerConfig(kind="walk", planner="capplanner", route=[Waypoint(x=goal[0], y=goal[1])]))
    if not plan_alone(scenario, out):
        return 1

    # The whole CapPlanner in the diagram: its route source puts the TLC in front of the BLC.
    result = simulate(scenario, out_dir=out / "walk", route_source=route_source_for(scenario))
    m = result.metrics
    print(f"walk {'succeeded' if m['success'] else 'FAILED (' + m['reason'] + ')'}, missions: {m['missions']}")
    if "sim_time_s" in m:  # a walk whose first mission found no plan never moved
        print(f"  {m['replans']} replans, final error {m['final_xy_error_m']:.3f} m, "
              f"{m['sim_time_s']:.1f} s simulated in {m['wall_time_s']:.1f} s; recording: {result.files['recording']}")
    return 0 if m["success"] else 1


if __name__ == "__main__":
    sys.exit(main())
