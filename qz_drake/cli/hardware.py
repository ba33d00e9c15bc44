"""``qz robot-sim``, the simulated robot driver behind the LCM protocol; ``qz servo``, the joint
PD that answers the robot from the references a planning process sends; ``qz lcm-relay``.

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
import signal

from qz_drake.errors import bad_value
from qz_drake.hardware.relay import DEFAULT_PORT as DEFAULT_RELAY_PORT
from qz_drake.hardware.relay import connect_lcm, tcpq_url
from qz_drake.hardware.scheduling import (DEFAULT_PRIORITY, DEFAULT_SIMULATOR_NICE, check_nice, check_priority,
                                         nice_level, realtime_priority, steady_collector)


def load_hardware_file(path: str | None):
    """The HardwareConfig of a YAML file (defaults for None)."""
    from qz_drake.config import read_text_file
    from qz_drake.hardware.config import HardwareConfig, load_hardware_config

    if path is None:
        return HardwareConfig()
    return load_hardware_config(read_text_file(path, "--hardware", "a protocol settings .yaml file"))


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def run_robot_sim(args) -> int:
    from pydrake.systems.analysis import Simulator

    from qz_drake.config import load_scenario
    from qz_drake.hardware.driver import QingzhuiRobotDriver
    from qz_drake.progress import ProgressReport
    from qz_drake.state_layout import BASE_POS

    scenario = load_scenario(args.scenario)
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise bad_value("--duration", args.duration, "must be a positive number of seconds")
    if not (math.isfinite(args.realtime_rate) and args.realtime_rate >= 0):
        raise bad_value("--realtime-rate", args.realtime_rate, "must be >= 0 (0: as fast as possible)")
    config = load_hardware_file(args.hardware)
    check_priority(args.realtime_priority)
    check_nice(args.nice)
    lcm = connect_lcm(args.lcm_url, "--lcm-url")
    meshcat = None
    if args.meshcat:
        from pydrake.geometry import Meshcat

        meshcat = Meshcat()
        print(f"meshcat: {meshcat.web_url()}", flush=True)
    driver = QingzhuiRobotDriver(scenario=scenario, lcm=lcm, config=config, meshcat=meshcat)
    simulator = Simulator(driver)
    simulator.set_target_realtime_rate(args.realtime_rate)
    # A plain kill (a script's `kill %1`, a test's terminate()) ends it as Ctrl-C does, with the
    # report.
    signal.signal(signal.SIGTERM, _interrupt)
    simulator.Initialize()
    end = math.inf if args.duration is None else args.duration
    with nice_level(args.nice) as niceness, realtime_priority(args.realtime_priority) as scheduling, \
            steady_collector() as collector, \
            ProgressReport("robot-sim", args.duration, unit="s simulated", digits=1) as report:
        if args.realtime_priority == 0:
            scheduling = niceness
        collector.start()
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
                      "realtime_factor": simulator.get_actual_realtime_rate(),
                      "base_position_m": x[BASE_POS].tolist(), "scheduling": scheduling, **collector.summary(),
                      **driver.counters(context)}))
    return 0


def run_servo(args) -> int:
    from qz_drake.config import load_scenario
    from qz_drake.hardware.servo import serve

    scenario = load_scenario(args.scenario)
    if args.parent_pid is not None and args.parent_pid <= 0:
        raise bad_value("--parent-pid", args.parent_pid, "must be a process id")
    config = load_hardware_file(args.hardware)
    check_priority(args.realtime_priority)
    with realtime_priority(args.realtime_priority) as scheduling:
        def ready():
            print(json.dumps({"servo": "serving", "lcm_url": args.lcm_url, "scheduling": scheduling}), flush=True)

        report = serve(scenario, lcm_url=args.lcm_url, config=config, parent_pid=args.parent_pid, ready=ready)
    print(json.dumps({**report, "scheduling": scheduling}), flush=True)
    return 1 if report["safe_stop"] else 0


def run_lcm_relay(args) -> int:
    from qz_drake.hardware.relay import LcmTcpRelay

    check_priority(args.realtime_priority)
    relay = LcmTcpRelay(args.port)
    # Stopped with Ctrl-C or a plain kill alike, so a script's `kill %1` also prints the counters.
    signal.signal(signal.SIGTERM, lambda *_: relay.close())
    with realtime_priority(args.realtime_priority) as scheduling, steady_collector() as collector:
        collector.start()
        print(json.dumps({"lcm_url": relay.url, "listening": True, "scheduling": scheduling}), flush=True)
        try:
            relay.serve_forever()
        except KeyboardInterrupt:
            pass
    print(json.dumps({**relay.counters(), **collector.summary()}), flush=True)
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("robot-sim", help="the simulated robot driver behind the LCM interface")
    p.add_argument("scenario", help="scenario YAML file (terrain, robot, control mode)")
    p.add_argument("--lcm-url", default=tcpq_url(DEFAULT_RELAY_PORT),
                   help="LCM URL (default: the `qz lcm-relay` on this machine; on a robot's network "
                        "udpm://239.255.76.67:7667?ttl=1)")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s] (default: until Ctrl-C)")
    p.add_argument("--realtime-rate", type=float, default=1.0, help="pacing (1: real time; 0: unpaced)")
    p.add_argument("--hardware", default=None, help="protocol settings YAML (qz_drake.hardware.config)")
    p.add_argument("--meshcat", action="store_true", help="draw the simulated robot in meshcat")
    p.add_argument("--realtime-priority", type=int, default=0,
                   help="SCHED_FIFO priority asked for (default 0: normal scheduling at --nice; its physics takes "
                        "most of a core, and a real-time process that does makes the kernel stop every real-time "
                        "process on that core for 50 ms now and then: docs/hardware.md)")
    p.add_argument("--nice", type=int, default=DEFAULT_SIMULATOR_NICE,
                   help=f"nice level under normal scheduling (default {DEFAULT_SIMULATOR_NICE}: the most CPU; "
                        "without the privilege it keeps its own)")
    p.set_defaults(func=run_robot_sim)

    p = subparsers.add_parser("servo", help="the joint PD answering the robot from a planning process's references")
    p.add_argument("scenario", help="scenario YAML file (gains, control mode, the standing start)")
    p.add_argument("--lcm-url", default=tcpq_url(DEFAULT_RELAY_PORT),
                   help="LCM URL of the robot and the planning process (default: the `qz lcm-relay` on this "
                        "machine)")
    p.add_argument("--hardware", default=None, help="protocol settings YAML (qz_drake.hardware.config)")
    p.add_argument("--parent-pid", type=int, default=None,
                   help="the planning process that started it: a safe stop when that process exits")
    p.add_argument("--realtime-priority", type=int, default=DEFAULT_PRIORITY,
                   help=f"SCHED_FIFO priority asked for, as a robot's control loop runs (default {DEFAULT_PRIORITY}; "
                        "0: normal scheduling); without the privilege it runs as a normal process")
    p.set_defaults(func=run_servo)

    p = subparsers.add_parser("lcm-relay", help="LCM's tcpq:// relay on 127.0.0.1, for processes on this machine")
    p.add_argument("--port", type=int, default=DEFAULT_RELAY_PORT,
                   help=f"TCP port on 127.0.0.1 (default {DEFAULT_RELAY_PORT}; 0: any free one, printed)")
    p.add_argument("--realtime-priority", type=int, default=DEFAULT_PRIORITY,
                   help=f"SCHED_FIFO priority asked for, as a robot's control loop runs (default {DEFAULT_PRIORITY}; "
                        "0: normal scheduling); without the privilege it runs as a normal process")
    p.set_defaults(func=run_lcm_relay)
