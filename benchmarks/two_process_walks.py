"""Two-process walks as a robot runs them: the controller against `qz robot-sim` at a real-time rate.

    python benchmarks/two_process_walks.py OUT.jsonl [--runs 10] [--rate 1] [--busy]
        [--scenario scenarios/walk_flat.yaml] [--servo process|inline] [--hardware FILE] [--keep DIR]

Each run starts `qz lcm-relay` on a free port on 127.0.0.1, `qz robot-sim SCENARIO` (the
simulated robot) and `qz simulate SCENARIO --station lcm --lcm-url URL` (the planning
process, which starts its `qz servo`; with `--servo inline`, the whole controller in one
process as before the servo existed), all at `--rate`, with the protocol's default budget
unless `--hardware` names another. `--busy` keeps a CPU-bound process running beside them
for the whole run (a second core's worth of other work on this 2-core machine). One JSON line
per run goes to OUT.jsonl (success, reason, safe stop, the servo's late holds and latency, the
driver's loop delay; where statuses stopped: the driver's longest wall time between two it sent
and the CPU time it spent in it, the servo's longest between two it received; each real-time
process's longest garbage-collector pause), and the summary is printed as the last line:
successes, the worst p99 latency and the longest gap between two commands.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def qz(*args) -> list[str]:
    return [sys.executable, "-m", "qz_drake.cli", *map(str, args)]


def _spin(stop) -> None:
    while not stop.is_set():
        sum(i * i for i in range(10000))


def one_walk(scenario: Path, rate: float, servo: str, hardware: Path | None, out: Path) -> dict:
    extra = ("--hardware", hardware) if hardware else ()
    relay = subprocess.Popen(qz("lcm-relay", "--port", 0), stdout=subprocess.PIPE, text=True)
    try:
        url = json.loads(relay.stdout.readline())["lcm_url"]
        driver = subprocess.Popen(qz("robot-sim", scenario, "--lcm-url", url, "--realtime-rate", rate, *extra),
                                  stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        try:
            start = time.monotonic()
            run = subprocess.run(qz("simulate", scenario, "--station", "lcm", "--lcm-url", url, "--realtime-rate",
                                    rate, "--servo", servo, "--out", out, *extra),
                                 capture_output=True, text=True, timeout=1800)
            wall = time.monotonic() - start
        finally:
            time.sleep(0.5)
            driver.terminate()
            driver_report = json.loads(driver.communicate(timeout=60)[0].splitlines()[-1])
    finally:
        relay.terminate()
        relay_lines = [ln for ln in relay.communicate(timeout=60)[0].splitlines() if ln.startswith("{")]
    relay_report = json.loads(relay_lines[-1]) if relay_lines else {}
    lines = [ln for ln in run.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        return {"success": False, "reason": f"no result (exit {run.returncode}): {run.stderr[-500:]}"}
    metrics = json.loads(lines[-1])
    servo_report = metrics.get("servo") or {}
    return {"success": bool(metrics["success"]), "reason": metrics.get("reason", ""),
            "safe_stop": metrics.get("safe_stop", ""), "final_xy_error_m": metrics.get("final_xy_error_m"),
            "sim_time_s": metrics.get("sim_time_s"), "wall_s": wall,
            "late_holds": servo_report.get("late_holds"), "late_hold_time_s": servo_report.get("late_hold_time_s"),
            "longest_late_hold_s": servo_report.get("longest_late_hold_s"),
            "latency_median_ms": servo_report.get("latency_median_ms"),
            "latency_p99_ms": servo_report.get("latency_p99_ms"), "latency_max_ms": servo_report.get("latency_max_ms"),
            "longest_command_gap_ms": servo_report.get("longest_command_gap_ms"),
            "interface": metrics.get("lcm_interface"),
            "driver_loop_delay_periods": driver_report.get("mean_loop_delay_periods"),
            "driver_longest_loop_delay_periods": driver_report.get("longest_loop_delay_periods"),
            "driver_safe_stop_reason": driver_report.get("safe_stop_reason"),
            # where statuses stopped: the driver's longest wall time between two it sent, and the
            # servo's between two it received [ms]
            "driver_longest_publish_gap_ms": driver_report.get("longest_publish_gap_ms"),
            "driver_longest_publish_gap_at_s": driver_report.get("longest_publish_gap_at_s"),
            "driver_longest_publish_gap_cpu_ms": driver_report.get("longest_publish_gap_cpu_ms"),
            "servo_longest_status_gap_ms": servo_report.get("longest_status_gap_ms"),
            # the longest pause of Python's garbage collector in each real-time process [ms]
            "gc_longest_pause_ms": {"servo": servo_report.get("gc_longest_pause_ms"),
                                    "driver": driver_report.get("gc_longest_pause_ms"),
                                    "relay": relay_report.get("gc_longest_pause_ms")}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument("--busy", action="store_true")
    parser.add_argument("--scenario", type=Path, default=ROOT / "scenarios" / "walk_flat.yaml")
    parser.add_argument("--servo", choices=("process", "inline"), default="process")
    parser.add_argument("--hardware", type=Path, default=None)
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR",
                        help="keep each run's output folder (metrics, plots, recording) as DIR/runK")
    args = parser.parse_args()
    stop = multiprocessing.Event()
    spinner = multiprocessing.Process(target=_spin, args=(stop,), daemon=True) if args.busy else None
    if spinner:
        spinner.start()
    results = []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            folders = Path(tmp) if args.keep is None else args.keep
            for k in range(args.runs):
                result = {"run": k, "rate": args.rate, "busy": args.busy, "servo": args.servo,
                          "scenario": args.scenario.name,
                          **one_walk(args.scenario, args.rate, args.servo, args.hardware, folders / f"run{k}")}
                results.append(result)
                with args.out.open("a") as f:
                    f.write(json.dumps(result) + "\n")
                print(json.dumps({key: result[key] for key in ("run", "success", "reason", "late_holds",
                                                               "latency_p99_ms", "longest_command_gap_ms",
                                                               "gc_longest_pause_ms", "driver_longest_publish_gap_ms",
                                                               "servo_longest_status_gap_ms")
                                  if key in result}), file=sys.stderr, flush=True)
    finally:
        stop.set()
    p99 = [r["latency_p99_ms"] for r in results if r.get("latency_p99_ms") is not None]
    gaps = [r["longest_command_gap_ms"] for r in results if r.get("longest_command_gap_ms") is not None]
    print(json.dumps({"runs": len(results), "successes": sum(r["success"] for r in results), "rate": args.rate,
                      "busy": args.busy, "servo": args.servo, "scenario": args.scenario.name,
                      "worst_latency_p99_ms": max(p99, default=None), "longest_command_gap_ms": max(gaps, default=None),
                      "late_holds": sum(r.get("late_holds") or 0 for r in results),
                      "longest_late_hold_s": max((r.get("longest_late_hold_s") or 0 for r in results), default=None)}))


if __name__ == "__main__":
    main()
