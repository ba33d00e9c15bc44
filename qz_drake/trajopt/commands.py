"""``qz blc``: one BLC solve from the command line, printed as one JSON object.

    qz blc --terrain NAME [--terrain-param k=v ...] --distance D --duration T [--topology NAME]
           [--robot qingzhui|hyq|quadruped] [--gait NAME] [--blc-param k=v ...] [--out sol.npz]
           [--json]

``--blc-param`` sets any field of BlcParameters (YAML values: numbers, true / false, names,
lists), e.g. ``--blc-param optimize_phase_durations=true --blc-param foothold_guess=stance``.

The terrain is one of qz_drake.terrain's generators (a gridded HeightMap, smoothed by the
BLC's terrain layer) or ``grid_map``. Exit status 0 when the solve succeeds, 1 when it does
not (a failed solve is a result), 2 for bad input.
"""

from __future__ import annotations

import dataclasses
import json

from qz_drake.errors import ConfigError, bad_value


def blc_parameters(items: list[str] | None):
    """BlcParameters from ``KEY=VALUE`` items (YAML values), each checked against the field's
    type; errors name ``--blc-param KEY`` and the value."""
    import yaml

    from qz_drake.trajopt.parameters import BlcParameters

    fields = {f.name: str(f.type) for f in dataclasses.fields(BlcParameters)}
    values = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--blc-param = {item!r}: expected KEY=VALUE")
        if key not in fields:
            raise bad_value("--blc-param", key, "not a BLC parameter (see qz_drake/trajopt/parameters.py)",
                            ConfigError)
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError:
            raise bad_value(f"--blc-param {key}", text, "not a YAML value", ConfigError) from None
        kind = fields[key]
        ok = {"bool": isinstance(value, bool),
              "int": isinstance(value, int) and not isinstance(value, bool),
              "float": isinstance(value, (int, float)) and not isinstance(value, bool),
              "str": isinstance(value, str),
              "float | None": value is None or (isinstance(value, (int, float)) and not isinstance(value, bool))
              }.get(kind, isinstance(value, (list, tuple)))
        if not ok:
            raise bad_value(f"--blc-param {key}", text, f"expected a value of type {kind}", ConfigError)
        values[key] = tuple(tuple(v) if isinstance(v, list) else v for v in value) \
            if isinstance(value, list) else value
    return BlcParameters(**values)


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
    params = blc_parameters(args.blc_param)
    solution = solve_blc(task, robot, heightmap, params)
    if args.out:
        solution.save_npz(args.out)
    result = {"success": bool(solution.success), "status": solution.status, "reason": solution.reason,
              "solve_time_s": solution.solve_time, "iterations": solution.iterations,
              "max_violation": solution.max_violation, "n_vars": solution.num_variables,
              "n_constraints": solution.num_constraints,
              # Each foot's stance and swing durations (optimised with optimize_phase_durations).
              "phase_durations": [list(d) for d in solution.contact_schedule.phase_durations],
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
    p.add_argument("--blc-param", action="append", metavar="KEY=VALUE",
                   help="a BlcParameters field, e.g. optimize_phase_durations=true")
    p.add_argument("--out", default=None, help="write the solution sampled at 100 Hz as .npz")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run)
