"""The ``qz`` command.

Subcommands are registered by the modules in ``_COMMAND_MODULES``; each has
``register(subparsers)`` and sets ``func(args) -> exit code`` on its parsers. Errors a user
can cause (QzError) print one line and exit with status 2; a failed solve or a fall is a
reported outcome with exit status 1.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import json
import math
import os
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


def _check_can_write_into(path: Path, field: str, value) -> None:
    """Refuses ``path`` (a folder, existing or to be made) that this process cannot write into:
    found before the work runs, not when its results are saved."""
    existing = path.absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise bad_value(field, str(value), f"cannot create a folder there: {existing} is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "folder is" if existing == path.absolute() else f"folder would be made in {existing}, which is"
        raise bad_value(field, str(value), f"not writable: the {what} read-only for this user")


def output_folder(value, field: str = "--out", *, create: bool = True) -> Path:
    """The folder ``value`` names, created if needed (``create``); an empty name, an existing
    file, or a folder this process cannot write into or make is a ConfigError naming ``field``.
    With ``create=False`` only the checks run, so that bad input leaves nothing behind."""
    if value is None or not str(value).strip():
        raise bad_value(field, "" if value is None else str(value),
                        "empty; name a folder to write into (an empty name is the current folder)")
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{field} = {str(value)!r}: is a file; expected a folder to write into")
    _check_can_write_into(path, field, value)
    if not create:
        return path
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"{field} = {str(value)!r}: cannot create the folder ({e.strerror})") from None
    return path


def output_file(value, field: str = "--out") -> Path:
    """Checks that the file ``value`` names can be written (its folder is made when it is
    written); errors name ``field``. Nothing is created."""
    if value is None or not str(value).strip():
        raise bad_value(field, "" if value is None else str(value), "empty; name a file to write")
    path = Path(value)
    if path.is_dir():
        raise bad_value(field, str(value), "is a folder; expected a file to write")
    if path.exists() and not os.access(path, os.W_OK):
        raise bad_value(field, str(value), "not writable: the file is read-only for this user")
    _check_can_write_into(path.parent, field, value)
    return path


def check_output_argument(args) -> None:
    """Checks ``args.out`` before a command runs: a folder (the default) or, where the command
    sets ``out_kind="file"``, a file; ``out_kind=None`` (an input named out) skips it. A
    read-only --out once failed only after the simulation had run."""
    value, kind = getattr(args, "out", None), getattr(args, "out_kind", "folder")
    if value is None or kind is None:
        return
    if kind == "file":
        output_file(value)
    else:
        output_folder(value, create=False)


def positive_seconds(value, field: str, limit: float | None = None) -> float | None:
    """``value`` as a finite positive duration of simulated time, at most ``limit`` (default:
    qz_drake.config.MAX_SIMULATED_TIME); None passes through; errors name ``field``."""
    from qz_drake.config import MAX_SIMULATED_TIME

    if value is None:
        return None
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{field} = {value}: must be a finite positive number of seconds")
    limit = MAX_SIMULATED_TIME if limit is None else limit
    if value > limit:
        raise bad_value(field, value, f"longer than the limit of {limit:g} s of simulated time")
    return float(value)


def one_of(names) -> str:
    """Help text listing the valid ``names`` (the package's own tuples, so it cannot go stale)."""
    return "one of: " + ", ".join(names)


def terrain_kinds_text() -> str:
    """Each terrain kind with its parameters and their defaults, one line each (from the
    generators' signatures), for help pages."""
    from qz_drake.terrain import TERRAIN_KINDS, grid_map_terrain

    def default(value):
        return ",".join(value) if isinstance(value, tuple) else f"{value:g}" if isinstance(value, float) else value

    lines = ["terrain kinds and their parameters (KEY=default; sizes in m; seed=N seeds the terrain;",
             "a negative stairs rise, step height or slope angle_deg goes down; |rise| <= run):"]
    for kind, generator in {**TERRAIN_KINDS, "grid_map": grid_map_terrain}.items():
        parameters = inspect.signature(generator).parameters.values()
        lines.append(f"  {kind}: " + " ".join(f"{p.name}={default(p.default)}" for p in parameters
                                               if p.name != "seed"))
    return "\n".join(lines)


def terrain_names() -> tuple[str, ...]:
    """The names ``--terrain`` / ``qz terrain`` take: the generators and grid_map."""
    from qz_drake.terrain import TERRAIN_KINDS

    return (*TERRAIN_KINDS, "grid_map")


def package_version() -> str:
    """The installed qz_drake's version (importlib.metadata)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("qz_drake")
    except PackageNotFoundError:
        return "unknown (not installed; run make setup)"


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
    output_folder(args.out)  # made once every input is checked, the hardware settings too
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
    if args.save is not None:
        if Path(args.save).is_dir():
            raise ConfigError(f"--save = {args.save!r}: is a folder; expected a .npz file")
        output_file(args.save, "--save")
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
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
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

    p = sub.add_parser("terrain", help="draw a generated terrain as a PNG", epilog=terrain_kinds_text(),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", metavar="KIND", help=f"terrain kind, {one_of(terrain_names())}")
    p.add_argument("--out", required=True, help=f"picture file to write ({', '.join(_PICTURE_SUFFIXES)})")
    p.add_argument("--param", action="append", metavar="KEY=VALUE",
                   help="generator parameter (see below), seed included")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--save", default=None, help="also save the heightmap as .npz")
    p.set_defaults(func=_cmd_terrain, out_kind="file")

    p = sub.add_parser("demo", help="the main job on the embedded default world")
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--duration", type=float, default=None, help="simulated time per run [s]")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("bench", help="run a benchmark suite (see benchmarks/)")
    from qz_drake.bench import SUITES

    p.add_argument("suite", choices=(*SUITES, "all"), metavar="SUITE", help=f"{one_of(SUITES)}, or all")
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
        check_output_argument(args)
        return int(args.func(args))
    except QzError as e:
        print(f"qz {args.command}: error: {e}", file=sys.stderr)
        return 2
    except UnicodeDecodeError as e:
        # A binary file where a text file was meant, read by a loader that did not name it.
        print(f"qz {args.command}: error: a file given is not UTF-8 text (byte 0x{e.object[e.start]:02x} at "
              f"offset {e.start}); expected a text file", file=sys.stderr)
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
