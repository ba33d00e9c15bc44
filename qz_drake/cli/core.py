"""The core commands: ``qz simulate``, ``qz terrain``, ``qz demo`` and ``qz bench``."""

from __future__ import annotations

import argparse
import contextlib
import json
from functools import partial
from pathlib import Path

from qz_drake.bench import SUITES, run_suite
from qz_drake.cli.arguments import (LazyText, one_of, output_file, output_folder, positive_seconds, prepare_scenario,
                                    terrain_kinds_text, terrain_names)
from qz_drake.errors import ConfigError


def _cmd_simulate(args) -> int:
    from qz_drake.cli.hardware import load_hardware_file
    from qz_drake.config import load_scenario
    from qz_drake.planning.capplanner_route import route_source_for
    from qz_drake.progress import ProgressReport, simulation_progress
    from qz_drake.simulation import simulate
    from qz_drake.station import make_station

    scenario = load_scenario(args.scenario)
    positive_seconds(args.duration, "--duration")
    output_folder(args.out, create=False)
    heightmap = prepare_scenario(scenario)
    # The map is built once: the station takes the checked one.
    station_factory, realtime_rate = partial(make_station, heightmap=heightmap), 0.0
    servo = contextlib.nullcontext()
    if args.station == "lcm":
        from qz_drake.hardware.loopback import make_lcm_loopback_station, make_remote_lcm_station
        from qz_drake.hardware.planning_station import ServoProcess, make_planning_lcm_station
        from qz_drake.hardware.relay import check_lcm_url

        # The station connects inside simulate(), after the work has begun.
        check_lcm_url(args.lcm_url, "--lcm-url")
        config = load_hardware_file(args.hardware)
        if args.lcm_url == "memq://":
            # The simulated robot driver in the same diagram, over an in-process LCM.
            station_factory = partial(make_lcm_loopback_station, config=config)
        elif args.servo == "process":
            # A driver in another process (qz robot-sim, the robot): the joint PD in a servo
            # process of its own, which no planning holds up; this one plans.
            station_factory = partial(make_planning_lcm_station, lcm_url=args.lcm_url, config=config)
            servo = ServoProcess(scenario, lcm_url=args.lcm_url, config=config, log=Path(args.out) / "servo.log")
        else:
            # Everything in this process, paced to real time (planning holds up the commands).
            station_factory = partial(make_remote_lcm_station, lcm_url=args.lcm_url, config=config)
            realtime_rate = args.realtime_rate
    output_folder(args.out)  # made once every input is checked, the hardware settings too
    with ProgressReport(f"simulate {scenario.name}: building", unit="s simulated", digits=1) as report, servo:
        result = simulate(scenario, duration=args.duration, out_dir=args.out, station_factory=station_factory,
                          realtime_rate=realtime_rate, route_source=route_source_for(scenario),
                          progress=simulation_progress(report, f"simulate {scenario.name}"))
    print(json.dumps(result.metrics))
    return 0 if result.metrics["success"] else 1


# What ``qz terrain --out`` can write (matplotlib's raster and vector formats).
_PICTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pdf", ".svg")


def _cmd_terrain(args) -> int:
    from qz_drake.config import TerrainConfig, parse_key_values
    from qz_drake.scene import make_heightmap
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
    result = run_suite(args.suite, repeats=args.repeats, quick=args.quick)
    print(json.dumps(result, indent=None if args.json else 2))
    return 0


def register(subparsers) -> None:
    """Adds ``simulate``, ``terrain``, ``demo`` and ``bench`` to the ``qz`` command."""
    p = subparsers.add_parser("simulate", help="simulate a scenario file")
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
    p.add_argument("--servo", choices=("process", "inline"), default="process",
                   help="with --station lcm and a network URL: process: the joint PD in a `qz servo` process "
                        "this command starts, fed with each plan's references, so that no planning holds up a "
                        "command; inline: everything in this process")
    p.set_defaults(func=_cmd_simulate)

    p = subparsers.add_parser("terrain", help="draw a generated terrain as a PNG", epilog=LazyText(terrain_kinds_text),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", metavar="KIND", help=LazyText(lambda: f"terrain kind, {one_of(terrain_names())}"))
    p.add_argument("--out", required=True, help=f"picture file to write ({', '.join(_PICTURE_SUFFIXES)})")
    p.add_argument("--param", action="append", metavar="KEY=VALUE",
                   help="generator parameter (see below), seed included")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--save", default=None, help="also save the heightmap as .npz")
    p.set_defaults(func=_cmd_terrain, out_kind="file")

    p = subparsers.add_parser("demo", help="the main job on the embedded default world")
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--duration", type=float, default=None, help="simulated time per run [s]")
    p.set_defaults(func=_cmd_demo)

    p = subparsers.add_parser("bench", help="run a benchmark suite (see benchmarks/)")
    p.add_argument("suite", choices=(*SUITES, "all"), metavar="SUITE", help=f"{one_of(SUITES)}, or all")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--repeats", type=int, default=None, help="runs per case (median reported)")
    p.add_argument("--quick", action="store_true", help="a small subset of the suite")
    p.set_defaults(func=_cmd_bench)
