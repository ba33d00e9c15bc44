"""The LCM hardware interface (issue 16): overhead per control step and status-to-command latency.

Three measurements over the first 10 s of ``walk_flat.yaml`` (torque mode, 500 Hz):

* ``latency``: wall time from the simulated driver's status publish (its hook, just before
  encoding) to the interface's command for that status (its hook, just before encoding and
  publishing), with the walking controller (IK tracker, joint PD of Eq. 7) evaluated in
  between: median and 99th percentile over every control period, in-process over memq://;
  also apart for the periods whose window holds the tracker's 200 Hz IK reference update and
  for those where the controller only evaluates the joint PD.
* ``interface_overhead``: the interface alone (no controller: zero torques in) replaying the
  statuses and poses recorded in that walk, one AdvanceTo per control period: LCM delivery,
  subscribers, decoding, watchdog, estimator, encoding and publishing, and Drake's stepping of
  the interface's events; median and 99th percentile per period.
* ``loopback_overhead``: (wall time of the walk over LCM - wall time of the same walk on the
  simulation station) / control periods. An upper bound on the interface's cost: it also holds
  the simulated driver's side (status encoding, the IMU and contact sensors it publishes).

Latency and interface overhead are also given as this process's CPU time over the same
windows (``*_cpu_time``): on a machine shared with other jobs the wall times include the time
the process waited for a core, the CPU times do not (CLOCK_PROCESS_CPUTIME_ID, ns resolution).

Not with ``--quick``: ``two_processes_walk_flat_rate_1``, the walk as a robot runs it, in three
processes at real time (benchmarks/two_process_walks.py): the servo's status -> command latency
and the longest gap between two commands, and each walk's outcome.
"""

import time
from pathlib import Path

import numpy as np

from qz_drake.config import load_scenario
from qz_drake.hardware.config import HardwareConfig
from qz_drake.hardware.loopback import make_lcm_loopback_station
from qz_drake.hardware.qz_lcm import qz_command
from qz_drake.simulation import simulate

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "walk_flat.yaml"


def _percentiles(values_s) -> dict:
    a = np.asarray(values_s) * 1e3
    return {"median_ms": float(np.median(a)), "p90_ms": float(np.percentile(a, 90)),
            "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max()), "samples": int(a.size)}


# The tracker's reference update period (InverseKinematicsTracker at 200 Hz). [us]
_TRACKER_PERIOD_US = 5000


def _walk_over_lcm(scenario, duration):
    published, statuses, poses = {}, [], []
    latencies = {"all": [], "joint_pd_only": [], "with_ik_update": [], "cpu": []}

    def on_status(m):
        published[m.sequence] = (time.perf_counter(), time.process_time())
        statuses.append(m.encode())
        return m

    def on_pose(m):
        poses.append(m.encode())
        return m

    def on_command(m):
        if m.mode != qz_command.MODE_SAFE_STOP and m.status_sequence in published:
            wall, cpu = published.pop(m.status_sequence)
            latency = time.perf_counter() - wall
            latencies["cpu"].append(time.process_time() - cpu)
            # Did the tracker's IK update fall between this status and this command?
            window_start = m.utime - round(0.5 * 1e6 * HardwareConfig().control_period)
            ik = (m.utime // _TRACKER_PERIOD_US) * _TRACKER_PERIOD_US > window_start
            latencies["all"].append(latency)
            latencies["with_ik_update" if ik else "joint_pd_only"].append(latency)
        return m

    def factory(*args, **kwargs):
        return make_lcm_loopback_station(*args, status_filter=on_status, pose_filter=on_pose,
                                         command_filter=on_command, **kwargs)
    metrics = simulate(scenario, duration=duration, station_factory=factory).metrics
    return metrics, latencies, statuses, poses


def _replay_interface(scenario, statuses, poses) -> list[float]:
    """Per-period wall times of the interface alone, fed the recorded messages."""
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from qz_drake.hardware.interface import make_hardware_interface

    config = HardwareConfig()
    lcm = DrakeLcm("memq://")
    builder = DiagramBuilder()
    interface, _ = make_hardware_interface(scenario, lcm=lcm, config=config)
    interface = builder.AddSystem(interface)
    zero = builder.AddSystem(ConstantVectorSource(np.zeros(18)))
    builder.Connect(zero.get_output_port(), interface.GetInputPort("joint_torque"))
    commands = []
    lcm.Subscribe(config.channels.command, commands.append)
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    h = config.control_period
    times, cpu_times = [], []
    for k, (status, pose) in enumerate(zip(statuses, poses)):
        start, cpu_start = time.perf_counter(), time.process_time()
        lcm.Publish(config.channels.status, status)
        lcm.Publish(config.channels.pose, pose)
        simulator.AdvanceTo((k + 1) * h)
        times.append(time.perf_counter() - start)
        cpu_times.append(time.process_time() - cpu_start)
    counters = interface.counters(simulator.get_context())
    if counters["safe_stops"] or len(commands) < len(statuses) - 1:
        raise RuntimeError(f"the replay did not run cleanly: {counters}, {len(commands)} commands")
    return times, cpu_times


def run(repeats: int = 1, quick: bool = False, duration: float = 10.0) -> dict:
    if quick:
        repeats, duration = 1, 2.0
    scenario = load_scenario(SCENARIO)
    steps = round(duration / HardwareConfig().control_period)
    runs = []
    for _ in range(repeats):
        direct = simulate(scenario, duration=duration).metrics
        over_lcm, latencies, statuses, poses = _walk_over_lcm(scenario, duration)
        replay, replay_cpu = _replay_interface(scenario, statuses, poses)
        runs.append({"latency": _percentiles(latencies["all"]),
                     "latency_joint_pd_only": _percentiles(latencies["joint_pd_only"]),
                     "latency_with_ik_update": _percentiles(latencies["with_ik_update"]),
                     "latency_cpu_time": _percentiles(latencies["cpu"]),
                     "interface_overhead": _percentiles(replay),
                     "interface_overhead_cpu_time": _percentiles(replay_cpu),
                     "loopback_overhead_ms": (over_lcm["wall_time_s"] - direct["wall_time_s"]) / steps * 1e3,
                     "wall_time_direct_s": direct["wall_time_s"], "wall_time_lcm_s": over_lcm["wall_time_s"],
                     "tracking_rms_direct_m": direct["tracking_rms_m"],
                     "tracking_rms_lcm_m": over_lcm["tracking_rms_m"],
                     "safe_stops": over_lcm["lcm_interface"]["safe_stops"] + over_lcm["lcm_driver"]["safe_stops"]})
    middle = sorted(runs, key=lambda r: r["latency"]["median_ms"])[len(runs) // 2]
    result = {"walk_flat_10s": {**middle, "sim_time_s": duration,
                                "control_period_ms": 1e3 * HardwareConfig().control_period, "repeats": repeats,
                                "latency_median_ms_all": [r["latency"]["median_ms"] for r in runs],
                                "interface_overhead_median_ms_all": [r["interface_overhead"]["median_ms"] for r in runs]}}
    if not quick:
        result["two_processes_walk_flat_rate_1"] = _two_process_walks(repeats)
    return result


def _two_process_walks(repeats: int) -> dict:
    """walk_flat as a robot runs it: `qz robot-sim`, the planning process and its `qz servo` at
    real time (two_process_walks.py): the servo's status -> command latency and the longest
    time between two of its commands, per walk, with the walk's outcome."""
    import importlib.util
    import tempfile

    spec = importlib.util.spec_from_file_location("two_process_walks", Path(__file__).with_name("two_process_walks.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    one_walk = module.one_walk

    walks = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeats):
            walk = one_walk(SCENARIO, 1.0, "process", None, Path(tmp) / f"walk{k}")
            walks.append({key: walk.get(key) for key in (
                "success", "reason", "latency_median_ms", "latency_p99_ms", "latency_max_ms",
                "longest_command_gap_ms", "late_holds", "longest_late_hold_s", "driver_loop_delay_periods")})
    return {"walks": walks, "successes": sum(w["success"] for w in walks),
            "worst_latency_p99_ms": max((w["latency_p99_ms"] or 0.0) for w in walks),
            "longest_command_gap_ms": max((w["longest_command_gap_ms"] or 0.0) for w in walks)}
