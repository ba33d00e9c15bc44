"""The ``qz`` command.

Subcommands are registered by the modules in ``_COMMAND_MODULES``; each has
``register(subparsers)`` and sets ``func(args) -> exit code`` on its parsers. Errors a user
can cause (QzError) print one line and exit with status 2; a failed solve or a fall is a
reported outcome with exit status 1.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import re
import sys
from pathlib import Path

from qz_drake.errors import ConfigError, QzError, bad_value

# Modules that add subcommands; a module that is not there yet is skipped.
_COMMAND_MODULES = (
    "qz_drake.trajopt.commands",
    "qz_drake.planning.commands",
    "qz_drake.planning.plan_command",
    "qz_drake.classification.commands",
    "qz_drake.capability.commands",
    "qz_drake.hardware.commands",
    "qz_drake.experiments.commands",
)


# A number or a comma-separated list of numbers, e.g. -5,-3 or -1e-2: an option's value, not an
# option. Maps are centred on the origin, so half of all coordinates are negative.
_NEGATIVE_NUMBERS = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(,\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)*$")


class _OneLineParser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # argparse reads "--start -5,-3" as two options; it accepts "-5" only.
        self._negative_number_matcher = _NEGATIVE_NUMBERS

    def error(self, message):  # one line, exit 2, as for every other bad input
        self.exit(2, f"{self.prog}: error: {message}\n")


def output_folder(value, field: str = "--out", *, create: bool = True) -> Path:
    """The folder ``value`` names, created if needed (``create``); an existing file or a folder
    that cannot be made is a ConfigError naming ``field``."""
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{field} = {str(value)!r}: is a file; expected a folder to write into")
    if not create:
        return path
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"{field} = {str(value)!r}: cannot create the folder ({e.strerror})") from None
    return path


def positive_seconds(value, field: str) -> float | None:
    """``value`` as a finite positive duration (None passes through); errors name ``field``."""
    if value is None:
        return None
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{field} = {value}: must be a finite positive number of seconds")
    return float(value)


def prepare_scenario(scenario):
    """The scenario's heightmap, after the checks that need it (start and waypoints on the map,
    a start the robot can stand on: qz_drake.config.check_against_map)."""
    from qz_drake.config import check_against_map
    from qz_drake.station import make_heightmap

    heightmap = make_heightmap(scenario.terrain, scenario.random_seed)
    check_against_map(scenario, heightmap)
    return heightmap


def parse_key_values(items: list[str] | None, field: str = "--param") -> dict[str, float]:
    """Parses ``k=v`` pairs into floats, naming the bad item on error."""
    out: dict[str, float] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{field} = {item!r}: expected KEY=VALUE")
        try:
            out[key] = float(value)
        except ValueError:
            raise ConfigError(f"{field} {key} = {value!r}: not a number") from None
    return out


def parse_names(text: str | None, field: str, valid) -> tuple[str, ...] | None:
    """A comma-separated list of names, each one of ``valid``; None passes through. Errors
    name ``field`` and the bad name."""
    if text is None:
        return None
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise bad_value(field, text, "expected a comma-separated list")
    for n in names:
        if n not in valid:
            raise bad_value(field, n, f"unknown (valid: {', '.join(valid)})")
    return names


def _cmd_simulate(args) -> int:
    from functools import partial

    from qz_drake.config import load_scenario
    from qz_drake.simulation import simulate
    from qz_drake.station import make_station

    scenario = load_scenario(args.scenario)
    positive_seconds(args.duration, "--duration")
    output_folder(args.out, create=False)
    heightmap = prepare_scenario(scenario)
    output_folder(args.out)
    # The map is built once: the station takes the checked one.
    station_factory, realtime_rate = partial(make_station, heightmap=heightmap), 0.0
    if args.station == "lcm":
        from qz_drake.hardware.commands import load_hardware_file
        from qz_drake.hardware.loopback import make_lcm_loopback_station, make_remote_lcm_station

        config = load_hardware_file(args.hardware)
        if args.lcm_url == "memq://":
            # The simulated robot driver in the same diagram, over an in-process LCM.
            station_factory = partial(make_lcm_loopback_station, config=config)
        else:
            # A driver in another process (qz robot-sim, the robot): both sides in real time.
            station_factory = partial(make_remote_lcm_station, lcm_url=args.lcm_url, config=config)
            realtime_rate = args.realtime_rate
    from qz_drake.progress import ProgressReport, simulation_progress

    with ProgressReport(f"simulate {scenario.name}: building", unit="s simulated", digits=1) as report:
        result = simulate(scenario, duration=args.duration, out_dir=args.out, station_factory=station_factory,
                          realtime_rate=realtime_rate,
                          progress=simulation_progress(report, f"simulate {scenario.name}"))
    print(json.dumps(result.metrics))
    return 0 if result.metrics["success"] else 1


# What ``qz terrain --out`` can write (matplotlib's raster and vector formats).
_PICTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pdf", ".svg")


def _cmd_terrain(args) -> int:
    from qz_drake.config import TerrainConfig
    from qz_drake.station import make_heightmap
    from qz_drake.viz.plots import plot_heightmap

    out = Path(args.out)
    if out.suffix.lower() not in _PICTURE_SUFFIXES:
        raise ConfigError(f"--out = {args.out!r}: expected a picture file ({', '.join(_PICTURE_SUFFIXES)})")
    if out.is_dir():
        raise ConfigError(f"--out = {args.out!r}: is a folder; expected a picture file")
    if args.save is not None and Path(args.save).is_dir():
        raise ConfigError(f"--save = {args.save!r}: is a folder; expected a .npz file")
    config = TerrainConfig(kind=args.name, params=parse_key_values(args.param))
    heightmap = make_heightmap(config, seed=args.seed)
    output_folder(out.parent, "--out")
    plot_heightmap(heightmap, out, title=f"{args.name} (seed {args.seed})")
    if args.save:
        heightmap.save_npz(args.save)
    print(json.dumps({"png": str(out), "shape": list(heightmap.heights.shape),
                      "resolution": heightmap.resolution,
                      "min_height": float(heightmap.heights.min()),
                      "max_height": float(heightmap.heights.max())}))
    return 0


def _cmd_demo(args) -> int:
    from qz_drake.demo import run_demo

    positive_seconds(args.duration, "--duration")
    output_folder(args.out)
    metrics = run_demo(args.out, duration=args.duration, progress=True)
    print(json.dumps(metrics))
    return 0 if metrics["success"] else 1


def _cmd_bench(args) -> int:
    from qz_drake.bench import run_suite

    result = run_suite(args.suite, repeats=args.repeats, quick=args.quick)
    print(json.dumps(result, indent=None if args.json else 2))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog="qz", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)

    p = sub.add_parser("simulate", help="simulate a scenario file")
    p.add_argument("scenario", help="scenario YAML file (see scenarios/)")
    p.add_argument("--out", default="out/simulate", help="output folder")
    p.add_argument("--duration", type=float, default=None, help="override the simulated time [s]")
    p.add_argument("--station", choices=("sim", "lcm"), default="sim",
                   help="sim: the simulation station; lcm: the LCM hardware interface against the "
                        "simulated robot driver, in-process over memq://")
    p.add_argument("--hardware", default=None, help="with --station lcm: protocol settings YAML")
    p.add_argument("--lcm-url", default="memq://",
                   help="with --station lcm: memq:// (the simulated driver in-process) or the URL of a "
                        "driver in another process (qz robot-sim, the robot)")
    p.add_argument("--realtime-rate", type=float, default=1.0,
                   help="with --station lcm and a network URL: pacing, the same as the driver's")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("terrain", help="draw a generated terrain as a PNG")
    p.add_argument("name", help="terrain kind, e.g. stairs, rough, grid_map")
    p.add_argument("--out", required=True, help="PNG file to write")
    p.add_argument("--param", action="append", metavar="KEY=VALUE", help="generator parameter")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--save", default=None, help="also save the heightmap as .npz")
    p.set_defaults(func=_cmd_terrain)

    p = sub.add_parser("demo", help="the main job on the embedded default world")
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--duration", type=float, default=None, help="simulated time per run [s]")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("bench", help="run a benchmark suite (see benchmarks/)")
    from qz_drake.bench import SUITES

    p.add_argument("suite", help=f"one of {', '.join(SUITES)}, or all")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--repeats", type=int, default=None, help="runs per case (median reported)")
    p.add_argument("--quick", action="store_true", help="a small subset of the suite")
    p.set_defaults(func=_cmd_bench)

    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name == name:
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except QzError as e:
        print(f"qz {args.command}: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader went away (`qz ... | head`): stop quietly, as Unix tools do, and keep
        # the interpreter's final flush from failing on the closed pipe.
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (collections write what finished first)
        print(f"qz {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as e:
        # A file the user named cannot be read or written (a folder where a file was meant, no
        # permission, a full disk): the same one line as for any other bad input.
        where = f"{e.filename}: " if e.filename else ""
        print(f"qz {args.command}: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
