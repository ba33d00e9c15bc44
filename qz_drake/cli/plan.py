"""``qz plan``: CapPlanner's top-level controller alone (paper 000 II-E.2, Fig. 6a).

The learned capability of every move and turn over the map in one batch, value iteration over
the capability MDP, the most likely path from the start to the goal and its BLC missions; with
``--out``, writes the utility map with the path (``plan.png``, the one use of matplotlib) and
``plan.json`` there, and without it draws and writes nothing. A goal no path reaches is a
reported outcome (exit 1); a goal off the map or where the robot cannot stand, a start where it
cannot stand, or a model of another robot is bad input (exit 2).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

from qz_drake.errors import bad_value


def run_plan(args) -> int:
    from qz_drake.cli.planning import parse_xy
    from qz_drake.capability.model import CapabilityModel
    from qz_drake.capability.model_commands import load_terrain
    from qz_drake.capability.patches import KINDS
    from qz_drake.planning.capability_mdp import CapabilityMdpConfig, plan
    from qz_drake.planning.guidance import split_missions
    from qz_drake.config import check_feet_on_map, feet_on_ground
    from qz_drake.scene import check_standable
    from qz_drake.robot.topology import TOPOLOGY_NAMES, get_topology

    start, goal = parse_xy(args.start, "--start"), parse_xy(args.goal, "--goal")
    if not 0 <= args.heading < 8:
        raise bad_value("--heading", args.heading, "expected a heading index 0..7 (k * 45 deg)")
    if args.topology not in TOPOLOGY_NAMES:
        raise bad_value("--topology", args.topology, f"expected one of {', '.join(TOPOLOGY_NAMES)}")
    if not 0.0 <= args.min_success <= 1.0:  # NaN too
        raise bad_value("--min-success", args.min_success, "must be a probability in [0, 1]")
    out = None if args.out is None else Path(args.out)
    if out is not None and out.exists() and not out.is_dir():
        raise bad_value("--out", str(out), "is a file, not a folder")
    heightmap = load_terrain(args.terrain, args.terrain_param, args.seed)
    # Checked before the model loads (seconds): heights off the map are the border's, so a map
    # narrower than the robot would let it stand on nothing.
    check_feet_on_map(heightmap, feet_on_ground(get_topology(args.topology).footholds_B, start, 0.0),
                      map_field="--terrain", map_value=args.terrain, position_field="--start",
                      position_value=args.start)
    check_standable(heightmap, start, args.topology, "--start")
    check_standable(heightmap, goal, args.topology, "--goal")
    model = CapabilityModel.load(args.model, device=args.device)
    topologies = [t for t in TOPOLOGY_NAMES if all(model.has_network(t, k) for k in KINDS)]
    if args.topology not in topologies:
        raise bad_value("--topology", args.topology, f"the model has no networks for it (it has "
                                                     f"{', '.join(topologies) or 'none'})")
    clock = time.perf_counter()
    result = plan(model, heightmap, start, args.heading, goal, start_topology=args.topology,
                  config=CapabilityMdpConfig(topologies=topologies))
    planning_time = time.perf_counter() - clock
    missions = split_missions(result.steps, start_yaw=args.heading * math.pi / 4) if result.reaches_goal else []
    reachable = result.reaches_goal and result.fall_free_probability >= args.min_success
    reason = "" if reachable else (
        "no path reaches the goal" if not result.reaches_goal else
        f"the best path's predicted chance of no fall {result.fall_free_probability:.3f} < {args.min_success:g}")
    png = None
    if out is not None:
        from qz_drake.capability.plots import plot_plan  # matplotlib: a third of a second to import

        out.mkdir(parents=True, exist_ok=True)
        png = plot_plan(heightmap, result, out / "plan.png", title=f"{args.terrain}: CapPlanner's TLC")
    cells = result.cells
    length = float(sum(math.hypot(*(cells[i + 1] - cells[i])) for i in range(len(cells) - 1))) if len(cells) > 1 else 0.0
    summary = {
        "success": bool(reachable), "reason": reason, "planning_time_s": planning_time,
        "iterations": int(result.solution.iterations), "converged": bool(result.solution.converged),
        "max_change": float(result.solution.max_change), "path_length_m": length,
        # Every action planned and walked at the first attempt; no action ending the walk.
        "predicted_success": float(result.success_probability),
        "predicted_fall_free": float(result.fall_free_probability), "missions": len(missions),
        "topology_changes": int(result.topology_changes), "states": int(result.mdp.goal_state + 2),
        # Per topology: the share of failures (orthogonal, diagonal, turn) the MDP took for the
        # BLC finding no plan (the robot stands) rather than the end of the walk.
        "plan_failures_from": result.mdp.plan_failure_source,
        "plan_failure_share": {t: [round(float(v), 4) for v in row]
                               for t, row in zip(result.mdp.topologies, result.mdp.plan_failure_share)},
        "start": list(start), "goal": list(goal), "png": None if png is None else str(png),
        "path": [{"x": s.x, "y": s.y, "heading": s.heading, "topology": s.action_topology, "motion": s.motion,
                  "success": s.success, "no_plan": s.stand} for s in result.steps],
        "mission_targets": [{"x": m.target[0], "y": m.target[1], "yaw": m.target[2], "topology": m.topology,
                             "success": m.success} for m in missions],
    }
    if out is not None:
        (out / "plan.json").write_text(json.dumps(summary, indent=1))
    if args.json:
        print(json.dumps({k: v for k, v in summary.items() if k not in ("path", "mission_targets")}))
    else:
        print(f"{'reachable' if reachable else 'UNREACHABLE'}: {len(missions)} missions, "
              f"{length:.1f} m, P(success) {result.success_probability:.2f}, P(no fall) "
              f"{result.fall_free_probability:.2f}, {result.topology_changes} topology "
              f"changes, VI {result.solution.iterations} iterations, {planning_time:.2f} s"
              + ("" if png is None else f" -> {png}"))
    return 0 if reachable else 1


def register(subparsers) -> None:
    """Adds ``plan`` to the ``qz`` command."""
    import argparse

    from qz_drake.cli.arguments import LazyText, one_of, terrain_kinds_text, terrain_names, topology_names

    p = subparsers.add_parser("plan", help="CapPlanner's TLC alone: utility map, guidance path, missions",
                              epilog=LazyText(terrain_kinds_text), formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--terrain", required=True, help=LazyText(
        lambda: f"a .npz / .yaml heightmap, a picture (its scale as --terrain-param resolution=M "
                f"max_height=M [min_height=M]), or a terrain generator, {one_of(terrain_names())}"))
    p.add_argument("--terrain-param", action="append", metavar="KEY=VALUE",
                   help="generator parameter (see below), seed included")
    p.add_argument("--seed", type=int, default=0, help="terrain seed")
    p.add_argument("--start", required=True, metavar="X,Y", help="start [m]")
    p.add_argument("--heading", type=int, default=0, help="start heading index k (yaw k * 45 deg)")
    p.add_argument("--topology", default="nominal",
                   help=LazyText(lambda: f"the robot's topology at the start, {one_of(topology_names())}"))
    p.add_argument("--goal", required=True, metavar="X,Y", help="goal [m]")
    p.add_argument("--model", default=None, help="capability model folder (default: the shipped model)")
    p.add_argument("--device", default=None,
                   help="where the networks run: cpu, cuda, cuda:N or auto (default: QZ_TORCH_DEVICE, else cpu)")
    p.add_argument("--min-success", type=float, default=0.05,
                   help="least predicted chance of the path arriving without a fall to call the goal reachable")
    p.add_argument("--out", default=None,
                   help="folder for plan.png (the utility map and path) and plan.json (default: none, nothing is "
                        "drawn or written)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_plan)
