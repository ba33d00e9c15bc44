"""``qz blc``: one BLC solve from the command line, printed as one JSON object.

    qz blc --terrain NAME [--terrain-param k=v ...] --distance D --duration T [--topology NAME]
           [--robot qingzhui|hyq|quadruped] [--gait NAME] [--out sol.npz] [--json]

The terrain is one of qz_drake.terrain's generators (a gridded HeightMap, smoothed by the
BLC's terrain layer) or ``grid_map``. Exit status 0 when the solve succeeds, 1 when it does
not (a failed solve is a result), 2 for bad input.
"""

from __future__ import annotations

import json

from qz_drake.errors import ConfigError, bad_value


def run(args) -> int:
    from qz_drake.cli import parse_key_values
    from qz_drake.config import TerrainConfig
    from qz_drake.robot.topology import TOPOLOGY_NAMES
    from qz_drake.station import make_heightmap
    from qz_drake.trajopt.robot_model import make_robot
    from qz_drake.trajopt.solver import BlcTask, solve_blc

    if not args.distance > 0:
        raise bad_value("--distance", args.distance, "must be positive", ConfigError)
    if not args.duration > 0:
        raise bad_value("--duration", args.duration, "must be positive", ConfigError)
    if args.topology not in TOPOLOGY_NAMES:
        raise bad_value("--topology", args.topology, f"expected one of {', '.join(TOPOLOGY_NAMES)}", ConfigError)
    heightmap = make_heightmap(TerrainConfig(kind=args.terrain,
                                             params=parse_key_values(args.terrain_param, "--terrain-param")))
    robot = make_robot(args.robot, args.topology)
    task = BlcTask(target=(args.distance, 0.0, 0.0), topology=args.topology, duration=args.duration, gait=args.gait)
    solution = solve_blc(task, robot, heightmap)
    if args.out:
        solution.save_npz(args.out)
    result = {"success": bool(solution.success), "status": solution.status, "reason": solution.reason,
              "solve_time_s": solution.solve_time, "iterations": solution.iterations,
              "max_violation": solution.max_violation, "n_vars": solution.num_variables,
              "n_constraints": solution.num_constraints,
              # The dense verdict's figures at 100 Hz (clearance, boxes, forces, residuals).
              "dense": None if solution.dense is None else solution.dense.summary()}
    print(json.dumps(result, indent=None if args.json else 2))
    return 0 if solution.success else 1


def register(subparsers) -> None:
    p = subparsers.add_parser("blc", help="solve one BLC trajectory optimisation")
    p.add_argument("--terrain", default="flat", help="terrain kind (qz terrain names, or grid_map)")
    p.add_argument("--terrain-param", action="append", metavar="KEY=VALUE", help="terrain parameter")
    p.add_argument("--distance", type=float, required=True, help="target distance along x [m]")
    p.add_argument("--duration", type=float, required=True, help="task duration T [s]")
    p.add_argument("--topology", default="nominal", help="Qingzhui topology")
    p.add_argument("--robot", default="qingzhui", help="qingzhui, hyq or quadruped")
    p.add_argument("--gait", default=None, help="gait name (default: the robot's)")
    p.add_argument("--out", default=None, help="write the solution sampled at 100 Hz as .npz")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run)
