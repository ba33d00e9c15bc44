"""``qz costmap`` and ``qz astar``: the cost maps and A* body path of paper 003 (section 2).

``qz costmap SCENARIO.yaml --out DIR`` writes the slope, roughness, step-height and body-cost
maps (Eq. 7-10) of the scenario's terrain as PNGs plus ``cost_map.npz`` and prints a JSON
summary. ``qz astar SCENARIO.yaml --out DIR --json`` plans the body-centre path (Eq. 16-20)
from the robot's initial position to the route's last waypoint (or ``--start`` / ``--goal``),
draws it on the cost map and prints found, length_m, cost, expansions and time_s; an
unreachable goal is a reported outcome with exit status 1.

``qz static-gait SCENARIO.yaml --out DIR`` (section 3-4) searches a static gait on a
static-gait scenario (:mod:`qz_drake.planning.static_gait_scenario`), walks it in Drake and
writes ``states.json``/``states.npz``, ``static_gait.png``, ``recording.html`` and
``metrics.json``; exit 0 when the search found every step and the walk reached the last state,
1 otherwise. ``qz gait-depth-study --out DIR`` measures the search's success rate against its
depth on random cuboid terrains (Fig. 10) and draws it.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from qz_drake.cli.arguments import output_folder
from qz_drake.errors import ConfigError, bad_value

ROBOTS = ("qingzhui", "quadruped")


def parse_xy(text: str | None, field: str) -> tuple[float, float] | None:
    """``"X,Y"`` in metres -> (x, y); None passes through. Errors name ``field``."""
    if text is None:
        return None
    parts = str(text).split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise bad_value(field, text, "expected X,Y in metres, e.g. 1.5,-0.2") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise bad_value(field, text, "must be finite")
    return x, y


def _footprint(robot: str):
    from qz_drake.terrain.features import Footprint

    if robot == "qingzhui":
        return Footprint.qingzhui()
    return Footprint.quadruped()


def _load(args):
    """Scenario and its heightmap, cropped to scenario.terrain.region when that is set."""
    from qz_drake.config import load_scenario
    from qz_drake.scene import make_heightmap

    scenario = load_scenario(args.scenario)
    heightmap = make_heightmap(scenario.terrain, scenario.random_seed)
    region = list(scenario.terrain.region)
    if region:
        heightmap = heightmap.crop(*region)
    return scenario, heightmap


def _summary(cost_map) -> dict:
    import numpy as np

    finite = np.isfinite(cost_map.body_cost)
    body = cost_map.body_cost[finite]
    return {
        "shape": list(cost_map.shape),
        "resolution": cost_map.resolution,
        "origin": list(cost_map.origin),
        "traversable_fraction": float(finite.mean()),
        "max_slope_deg": float(np.degrees(cost_map.body.slope.max())),
        "max_roughness_m": float(cost_map.body.roughness.max()),
        "max_step_height_m": float(cost_map.body.step_height.max()),
        "mean_body_cost": float(body.mean()) if body.size else math.nan,
    }


def save_cost_map_npz(cost_map, path: str | Path) -> Path:
    """The feature and cost arrays of a CostMap (inf = blocked) with resolution and origin."""
    import numpy as np

    path = Path(path)
    np.savez_compressed(path, slope=cost_map.body.slope, roughness=cost_map.body.roughness,
                        step_height=cost_map.body.step_height, body_cost=cost_map.body_cost,
                        feet_cost=cost_map.feet_cost, heading_cost=cost_map.heading_cost(),
                        resolution=cost_map.resolution, origin=np.asarray(cost_map.origin))
    return path


def run_costmap(args) -> int:
    from qz_drake.terrain.features import build_cost_map
    from qz_drake.viz.costmap_plots import plot_cost_maps

    out = output_folder(args.out, create=False)
    scenario, heightmap = _load(args)
    cost_map = build_cost_map(heightmap, footprint=_footprint(args.robot))
    pngs = plot_cost_maps(cost_map, out, title=scenario.name)
    npz = save_cost_map_npz(cost_map, out / "cost_map.npz")
    summary = {"scenario": scenario.name, "robot": args.robot, **_summary(cost_map),
               "png": {k: str(v) for k, v in pngs.items()}, "npz": str(npz)}
    print(json.dumps(summary, indent=None if args.json else 2))
    return 0


def _endpoints(args, scenario) -> tuple[tuple[float, float], tuple[float, float]]:
    start = parse_xy(args.start, "--start")
    if start is None:
        start = parse_xy(",".join(str(v) for v in scenario.robot.initial_xy), "scenario.robot.initial_xy")
    goal = parse_xy(args.goal, "--goal")
    if goal is None:
        if not scenario.controller.route:
            raise bad_value("--goal", None, "not given and scenario.controller.route has no waypoint")
        last = scenario.controller.route[-1]
        goal = (float(last.x), float(last.y))
    return start, goal


def _check_on_map(heightmap, point, field: str) -> None:
    xmin, xmax, ymin, ymax = heightmap.bounds
    if not (xmin <= point[0] <= xmax and ymin <= point[1] <= ymax):
        raise bad_value(field, f"{point[0]:g},{point[1]:g}",
                        f"off the map (x in [{xmin:g}, {xmax:g}], y in [{ymin:g}, {ymax:g}])")


def blocked_because(cost_map, xy) -> str:
    """Why the cost map blocks the cell of world point ``xy``, in words, or "" if it does not.

    The body cost (paper 003, 2.1.4) blocks a cell where the step height within the body's disc
    (radius ``body_features.radius`` around it) exceeds ``body_cost.max_step_height``: a wall
    within reach of the trunk blocks the cell, also where the walker's feet could still find
    footholds beside it. A walk that reaches such a goal therefore does not contradict A*."""
    import numpy as np

    row, col = cost_map.cell(*xy)
    heading = cost_map.heading_cost()[:, row, col]
    if np.isfinite(heading).any():
        return ""
    config = cost_map.config
    step = float(cost_map.body.step_height[row, col])
    limit = float(config.body_cost.max_step_height)
    radius = float(config.body_features.radius)
    if step > limit:
        return (f"a step of {step:.2f} m lies within {radius:g} m of it (the body's disc), above the "
                f"cost map's max_step_height {limit:g} m; the walker may still reach it where its feet "
                f"find footholds beside the step (the cost map is conservative)")
    return "the feet cost is infinite for every heading (no foothold triangle fits)"


def run_astar(args) -> int:
    import numpy as np

    from qz_drake.planning.astar import AStarConfig, astar
    from qz_drake.terrain.features import build_cost_map
    from qz_drake.viz.costmap_plots import plot_cost_map_path

    if not (math.isfinite(args.safety_weight) and 0.0 <= args.safety_weight <= 1.0):
        raise bad_value("--safety-weight", args.safety_weight, "must be in [0, 1]")
    if args.margin is not None and not (math.isfinite(args.margin) and args.margin >= 0.0):
        raise bad_value("--margin", args.margin, "must be >= 0 metres")
    output_folder(args.out, create=False)
    scenario, heightmap = _load(args)
    start, goal = _endpoints(args, scenario)
    _check_on_map(heightmap, start, "--start")
    _check_on_map(heightmap, goal, "--goal")
    if args.margin is not None:
        # Plan on the box around start and goal only: a big map costs seconds per feature.
        m = args.margin
        heightmap = heightmap.crop(min(start[0], goal[0]) - m, max(start[0], goal[0]) + m,
                                   min(start[1], goal[1]) - m, max(start[1], goal[1]) + m)
    cost_map = build_cost_map(heightmap, footprint=_footprint(args.robot))
    config = AStarConfig(distance_weight=1.0 - args.safety_weight, safety_weight=args.safety_weight)
    result = astar(cost_map, start, goal, config=config)

    out = output_folder(args.out)
    blocked = {name: why for name, point in (("start", start), ("goal", goal))
               if (why := blocked_because(cost_map, point))} if not result.found else {}
    reason = result.reason
    for name, point in (("start", start), ("goal", goal)):
        # The search names cells (row, col); a user gave metres.
        if reason.startswith(f"{name} (") and "blocked" in reason:
            reason = f"{name} ({point[0]:g}, {point[1]:g}) m is blocked"
    png = plot_cost_map_path(cost_map, out / "astar_path.png",
                             paths_xy={f"safety weight {args.safety_weight:g}": result.xy},
                             start_xy=start, goal_xy=goal,
                             title=f"{scenario.name}: A* ({reason})")
    np.savez_compressed(out / "astar_path.npz", xy=result.xy, cells=result.cells, headings=result.headings)
    summary = {
        "scenario": scenario.name,
        "robot": args.robot,
        "found": bool(result.found),
        "reason": reason,
        "start": list(start),
        "goal": list(goal),
        "length_m": result.length if result.found else None,
        "cost": result.cost if result.found else None,
        "mean_cell_cost": result.mean_cell_cost if result.found else None,
        "expansions": int(result.expansions),
        "time_s": float(result.time_s),
        "safety_weight": args.safety_weight,
        "map_shape": list(cost_map.shape),
        "png": str(png),
    }
    if blocked:
        summary["blocked_because"] = blocked
    print(json.dumps(summary, indent=None if args.json else 2))
    return 0 if result.found else 1


def _positive_int(text: str, field: str, most: int | None = None, unit: str = "") -> int:
    """``text`` as a whole number, at least 1 and at most ``most`` (``unit`` names what it
    counts); errors name ``field``."""
    try:
        value = int(text)
    except (TypeError, ValueError):
        raise bad_value(field, text, "expected a whole number") from None
    if value < 1:
        raise bad_value(field, value, "must be >= 1")
    if most is not None and value > most:
        raise bad_value(field, value, f"more than {most} {unit}")
    return value


def run_static_gait_command(args) -> int:
    import sys

    from qz_drake.planning.static_gait import MAX_DEPTH
    from qz_drake.planning.static_gait_scenario import check_walk_length, load_static_gait_scenario, run_static_gait

    scenario = load_static_gait_scenario(args.scenario)
    if args.depth is not None:
        scenario.depth = _positive_int(args.depth, "--depth", MAX_DEPTH, "steps looked ahead")
    if args.steps is not None:
        scenario.steps = _positive_int(args.steps, "--steps")
        check_walk_length(scenario, "--steps")  # the walk's bound, also MAX_STEPS
    metrics = run_static_gait(scenario, args.out, progress=not args.json and sys.stderr.isatty())
    metrics = {k: v for k, v in metrics.items() if k != "scenario_yaml"}
    print(json.dumps(metrics, indent=None if args.json else 2))
    return 0 if metrics["success"] else 1


def _depth_list(text: str) -> list[int]:
    from qz_drake.planning.static_gait import MAX_DEPTH

    try:
        depths = [int(v) for v in str(text).split(",")]
    except ValueError:
        raise bad_value("--depths", text, "expected depths like 1,2,3,4") from None
    if not depths or min(depths) < 1 or max(depths) > MAX_DEPTH:
        raise bad_value("--depths", text, f"depths must be within [1, {MAX_DEPTH}] steps ahead")
    return depths


def run_depth_study_command(args) -> int:
    import sys

    from qz_drake.planning.depth_study import DEPTH_STUDY_GAIT, MAX_TERRAINS, depth_study
    from qz_drake.planning.static_gait import MAX_CANDIDATES, MAX_NODES, MAX_STEPS
    from qz_drake.viz.costmap_plots import plot_depth_study

    depths = _depth_list(args.depths)
    terrains = _positive_int(args.terrains, "--terrains", MAX_TERRAINS, "terrains")
    steps = _positive_int(args.steps, "--steps", MAX_STEPS, "swings")
    if not (math.isfinite(args.max_height) and args.max_height >= 0):
        raise bad_value("--max-height", args.max_height, "must be >= 0 metres")
    if args.seed < 0:
        raise bad_value("--seed", args.seed, "must be >= 0 (terrain k has seed SEED + k)")
    config = dataclasses.replace(DEPTH_STUDY_GAIT)
    for name, most, unit in (("height_count", MAX_CANDIDATES, "body heights"), ("pitch_count", MAX_CANDIDATES, "pitches"),
                             ("roll_count", MAX_CANDIDATES, "rolls"), ("max_nodes", MAX_NODES, "states per step")):
        value = getattr(args, name)
        if value is not None:
            setattr(config, name, _positive_int(value, "--" + name.replace("_", "-"), most, unit))
    study = depth_study(depths, terrains, steps=steps, max_height=args.max_height, seed=args.seed, config=config,
                        progress=not args.json and sys.stderr.isatty())
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    summary = study.to_dict()
    summary["candidates"] = {name: getattr(config, name) for name in
                             ("foothold_count", "height_count", "pitch_count", "roll_count", "max_nodes")}
    summary["png"] = str(plot_depth_study(study, out / "depth_study.png"))
    (out / "depth_study.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=None if args.json else 2))
    return 0


def register(subparsers) -> None:
    """Adds ``costmap``, ``astar``, ``static-gait`` and ``gait-depth-study`` to the ``qz`` command."""
    p = subparsers.add_parser("costmap", help="terrain feature and cost maps (paper 003 Eq. 2-16)")
    p.add_argument("scenario", help="scenario YAML file (see scenarios/)")
    p.add_argument("--out", default="out/costmap", help="output folder")
    p.add_argument("--robot", choices=ROBOTS, default="qingzhui", help="footprint of the feet cost")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_costmap)

    p = subparsers.add_parser("astar", help="A* body path over the cost map (paper 003 Eq. 16-20)")
    p.add_argument("scenario", help="scenario YAML file (see scenarios/)")
    p.add_argument("--out", default="out/astar", help="output folder")
    p.add_argument("--robot", choices=ROBOTS, default="qingzhui", help="footprint of the feet cost")
    p.add_argument("--start", default=None, metavar="X,Y",
                   help="start [m]; default scenario.robot.initial_xy")
    p.add_argument("--goal", default=None, metavar="X,Y",
                   help="goal [m]; default the last waypoint of scenario.controller.route")
    p.add_argument("--safety-weight", type=float, default=0.5,
                   help="w_2 of Eq. 17 in [0, 1]; distance gets 1 - w_2")
    p.add_argument("--margin", type=float, default=2.0,
                   help="plan on the box around start and goal grown by this much [m]")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_astar)

    p = subparsers.add_parser("static-gait", help="search a static gait and walk it in Drake (paper 003 sec. 3-4)")
    p.add_argument("scenario", help="static-gait scenario YAML (see scenarios/static_gait/)")
    p.add_argument("--out", default="out/static_gait", help="output folder")
    p.add_argument("--depth", default=None, help="override scenario.depth: steps searched ahead")
    p.add_argument("--steps", default=None, help="override scenario.steps: swings to take")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_static_gait_command)

    p = subparsers.add_parser("gait-depth-study",
                              help="static-gait search success rate against depth on cuboid terrains (Fig. 10)")
    p.add_argument("--out", default="out/gait_depth_study", help="output folder")
    p.add_argument("--terrains", default="50", help="number of seeded cuboid terrains")
    p.add_argument("--depths", default="1,2,3,4", help="comma-separated search depths")
    p.add_argument("--steps", default="12", help="swings to find on each terrain")
    p.add_argument("--max-height", type=float, default=0.025, help="largest cuboid height [m]")
    p.add_argument("--seed", type=int, default=0, help="terrain k has seed SEED + k")
    for name, default in (("height-count", 3), ("pitch-count", 1), ("roll-count", 1), ("max-nodes", 2000)):
        p.add_argument(f"--{name}", default=None,
                       help=f"candidates of the search (default {default}, depth_study.DEPTH_STUDY_GAIT)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_depth_study_command)
