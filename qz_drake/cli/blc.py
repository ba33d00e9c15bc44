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
import math

from qz_drake.cli.arguments import LazyText, one_of, terrain_kinds_text, terrain_names, topology_names
from qz_drake.errors import ConfigError, bad_value

# Longest task the command solves. The program grows with T: measured peak memory 0.28 GB at
# 5 s, 0.48 GB at 20 s, 0.86 GB at 60 s (about 10 MB per second of plan); a user's 1e9 s was
# killed by the kernel at 24 GB. A BLC task is one local mission of a few seconds. [s]
MAX_BLC_DURATION = 120.0
# Most samples of one time series (body nodes, dynamics, kinematics, clearance, dense check):
# the default finest one, 0.01 s, over MAX_BLC_DURATION.
MAX_BLC_SAMPLES = 12_000
# The BlcParameters fields that set a sample spacing [s], and the one rate [1/s].
_SPACINGS = ("base_node_spacing", "dynamics_dt", "linear_dynamics_dt", "kinematics_dt", "swing_clearance_dt")
_RATES = ("dense_check_rate",)


def check_blc_size(duration: float, params) -> None:
    """Refuses a task whose program would not fit: a duration beyond MAX_BLC_DURATION or a
    sample spacing that makes a series longer than MAX_BLC_SAMPLES, before anything is built."""
    if not (math.isfinite(duration) and duration > 0):
        raise bad_value("--duration", duration, "must be a finite positive number of seconds", ConfigError)
    if duration > MAX_BLC_DURATION:
        raise bad_value("--duration", duration, f"longer than the limit of {MAX_BLC_DURATION:g} s for one BLC task "
                                                f"(its program grows by about 10 MB per second)", ConfigError)
    for name in _SPACINGS + _RATES:
        value = getattr(params, name)
        samples = duration * value if name in _RATES else duration / value if value > 0 else 0
        if samples > MAX_BLC_SAMPLES:
            raise bad_value(f"--blc-param {name}", value, f"{samples:.3g} samples over {duration:g} s; at most "
                                                          f"{MAX_BLC_SAMPLES} in one series", ConfigError)


def blc_parameters(items: list[str] | None):
    """BlcParameters from ``KEY=VALUE`` items (YAML values), each checked against the field's
    type; errors name ``--blc-param KEY`` and the value."""
    import yaml

    from qz_drake.config import yaml_load
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
            value = yaml_load(text)
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
    from qz_drake.config import TerrainConfig, check_feet_on_map, parse_key_values
    from qz_drake.robot.topology import TOPOLOGY_NAMES
    from qz_drake.scene import make_heightmap
    from qz_drake.trajopt.robot_model import make_robot
    from qz_drake.trajopt.solver import BlcTask, solve_blc

    if not (math.isfinite(args.distance) and args.distance > 0):
        raise bad_value("--distance", args.distance, "must be a finite positive number of metres", ConfigError)
    if args.topology not in TOPOLOGY_NAMES:
        raise bad_value("--topology", args.topology, f"expected one of {', '.join(TOPOLOGY_NAMES)}", ConfigError)
    params = blc_parameters(args.blc_param)
    check_blc_size(args.duration, params)
    terrain_params = parse_key_values(args.terrain_param, "--terrain-param")
    heightmap = make_heightmap(TerrainConfig(kind=args.terrain, params=terrain_params))
    robot = make_robot(args.robot, args.topology)
    # Heights off the map are the border's: a map narrower than the robot would let it stand on nothing.
    field = "--terrain-param" if terrain_params else "--terrain"
    value = args.terrain_param if terrain_params else args.terrain
    check_feet_on_map(heightmap, robot.nominal_footholds, map_field=field, map_value=value, position_field=field,
                      position_value=value, robot=robot.name)
    task = BlcTask(target=(args.distance, 0.0, 0.0), topology=args.topology, duration=args.duration, gait=args.gait)
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
    import argparse

    # The names the help texts list, looked up when a help page is shown.
    def robots() -> str:
        from qz_drake.trajopt.robot_model import ROBOT_NAMES

        return one_of(ROBOT_NAMES)

    def gaits() -> str:
        from qz_drake.trajopt.gait import GAIT_NAMES

        return f"gait (default: the robot's), {one_of(GAIT_NAMES)}"

    p = subparsers.add_parser("blc", help="solve one BLC trajectory optimisation", epilog=LazyText(terrain_kinds_text),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--terrain", default="flat", metavar="KIND",
                   help=LazyText(lambda: f"terrain kind, {one_of(terrain_names())}"))
    p.add_argument("--terrain-param", action="append", metavar="KEY=VALUE",
                   help="terrain parameter (see below), seed included")
    p.add_argument("--distance", type=float, required=True, help="target distance along x [m]")
    p.add_argument("--duration", type=float, required=True,
                   help=f"task duration T [s], at most {MAX_BLC_DURATION:g}")
    p.add_argument("--topology", default="nominal",
                   help=LazyText(lambda: f"Qingzhui topology, {one_of(topology_names())}"))
    p.add_argument("--robot", default="qingzhui", help=LazyText(robots))
    p.add_argument("--gait", default=None, help=LazyText(gaits))
    p.add_argument("--blc-param", action="append", metavar="KEY=VALUE",
                   help="a BlcParameters field, e.g. optimize_phase_durations=true")
    p.add_argument("--out", default=None, help="write the solution sampled at 100 Hz as .npz")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run, out_kind="file")
