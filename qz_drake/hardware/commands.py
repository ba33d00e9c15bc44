"""``qz robot-sim``: the simulated robot driver behind the LCM protocol (issue 16).

``qz robot-sim SCENARIO.yaml --lcm-url URL [--duration S] [--realtime-rate R]
[--hardware CONFIG.yaml] [--meshcat]`` runs the scenario's simulation station as a robot driver: paced to
real time, it publishes qz_status and qz_pose at the control rate and applies the newest
qz_command (QingzhuiRobotDriver). A controller on the same LCM network reaches it through
``make_station(scenario, backend="lcm", lcm_url=URL)``. It prints the command link's counters
as one JSON line when the duration has passed or on Ctrl-C.
"""

from __future__ import annotations

import json
import math

from qz_drake.errors import bad_value


def load_hardware_file(path: str | None):
    """The HardwareConfig of a YAML file (defaults for None)."""
    from qz_drake.config import read_text_file
    from qz_drake.hardware.config import HardwareConfig, load_hardware_config

    if path is None:
        return HardwareConfig()
    return load_hardware_config(read_text_file(path, "--hardware", "a protocol settings .yaml file"))


def run_robot_sim(args) -> int:
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from qz_drake.config import load_scenario
    from qz_drake.hardware.driver import QingzhuiRobotDriver
    from qz_drake.progress import ProgressReport

    scenario = load_scenario(args.scenario)
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise bad_value("--duration", args.duration, "must be a positive number of seconds")
    if not (math.isfinite(args.realtime_rate) and args.realtime_rate >= 0):
        raise bad_value("--realtime-rate", args.realtime_rate, "must be >= 0 (0: as fast as possible)")
    config = load_hardware_file(args.hardware)
    try:
        lcm = DrakeLcm(args.lcm_url)
    except RuntimeError as e:
        raise bad_value("--lcm-url", args.lcm_url, str(e)) from None
    meshcat = None
    if args.meshcat:
        from pydrake.geometry import Meshcat

        meshcat = Meshcat()
        print(f"meshcat: {meshcat.web_url()}", flush=True)
    driver = QingzhuiRobotDriver(scenario=scenario, lcm=lcm, config=config, meshcat=meshcat)
    simulator = Simulator(driver)
    simulator.set_target_realtime_rate(args.realtime_rate)
    simulator.Initialize()
    end = math.inf if args.duration is None else args.duration
    with ProgressReport("robot-sim", args.duration, unit="s simulated", digits=1) as report:
        try:
            while simulator.get_context().get_time() < end:
                simulator.AdvanceTo(min(end, simulator.get_context().get_time() + 1.0))
                counters = driver.counters(simulator.get_context())
                report.update(simulator.get_context().get_time(), status=f"safe stop: {counters['safe_stop_reason']}"
                              if counters["safe_stop_latched"] else "")
        except KeyboardInterrupt:
            pass
    context = simulator.get_context()
    x = driver.GetOutputPort("true_state").Eval(context)
    print(json.dumps({"sim_time_s": float(context.get_time()), "lcm_url": args.lcm_url,
                      "base_position_m": x[4:7].tolist(), **driver.counters(context)}))
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("robot-sim", help="the simulated robot driver behind the LCM interface")
    p.add_argument("scenario", help="scenario YAML file (terrain, robot, control mode)")
    p.add_argument("--lcm-url", default="udpm://239.255.76.67:7667?ttl=0",
                   help="LCM URL (default: UDP multicast on this machine only, ttl=0)")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s] (default: until Ctrl-C)")
    p.add_argument("--realtime-rate", type=float, default=1.0, help="pacing (1: real time; 0: unpaced)")
    p.add_argument("--hardware", default=None, help="protocol settings YAML (qz_drake.hardware.config)")
    p.add_argument("--meshcat", action="store_true", help="draw the simulated robot in meshcat")
    p.set_defaults(func=run_robot_sim)
