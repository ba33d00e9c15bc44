"""Start sweeps of the BLC (issue 52): 1 m missions along a row of a Fig. 9 world, started every
0.1 m across a feature (up a flight, down a platform edge), each from the BLC's own plan of the
metres before it, as a walk asks for them; every mission whose first solve is refused is solved
again on each rung of the BLC ladder, one at a time, so that any order of rungs can be scored.

    python benchmarks/blc_refusals.py OUT.jsonl --world stairs-hard-3 --feature up [--y 0.03]
    python benchmarks/blc_refusals.py OUT.jsonl --replay RUN [RUN ...]


One JSON line per start: the start (x, y), its first solve (success, reason, iterations, wall
time), the lead-in (how many missions brought the robot there, and on which rungs), and for a
refused first solve each rung's outcome. Resumable: starts already in OUT are skipped.
``--replay`` takes instead the refused missions of recorded walks (Fig. 9 results folders or a
tuning's, walked with ``--record-missions``): each is solved again from the very start its BLC
was given (whether the refusal reproduces), then on each rung; with ``--walk LADDER`` each is also
walked in Drake from that stance (the robot standing at the recorded base x, y, yaw with its
feet where they were, on the ground) by the BLC with that ladder, judged by the strict verdict.
``--summary OUT.jsonl ...`` prints the table of BENCHMARKS.md "blc ladder" for the files given.
``--blc NAME=VALUE`` (repeatable) changes a BlcParameters field for every solve and walk (e.g.
``--blc leg_clearance_softmin=300``).

The BLC is the Fig. 9 experiment's (30 Ipopt iterations, 30 s, MissionTiming's speed and
phase), the missions the BLC system's (qz_drake.systems.blc_plan.blc_mission_planner), the
starts plan ends (the BLC level; the robot in Drake starts from what it measures). Worlds of
seeds 50-99 are refused: they are kept for checks outside the project.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

RUNGS = ("cycles+1", "split", "cycles+2", "split+1", "short")
STEP = 0.1
COUNT = 36
BEFORE = 2.5
MISSION = 1.0


def feature_edge(heightmap, y: float, feature: str) -> float:
    """x of the first rise (``up``) or of the first drop after it (``down``) along the row at y:
    the boundary between the two cells. [m]"""
    H = np.asarray(heightmap.heights)
    res, (ox, oy) = heightmap.resolution, heightmap.origin
    row = H[int(round((y - oy) / res))]
    change = np.nonzero(np.abs(np.diff(row)) > 1e-6)[0]
    rises = [c for c in change if row[c + 1] > row[c]]
    if not rises:
        raise SystemExit(f"no rise along y = {y:g}")
    if feature == "up":
        c = rises[0]
    else:
        drops = [c for c in change if row[c + 1] < row[c] and c > rises[0]]
        if not drops:
            raise SystemExit(f"no drop after the rise along y = {y:g}")
        c = drops[0]
    return float(ox + res * (c + 0.5))


def level(heightmap, x: float, y: float, half: float = 0.5) -> bool:
    """Whether the ground is level within ``half`` of (x, y) along x and y (a standing start)."""
    xs = x + np.linspace(-half, half, 21)
    ys = y + np.linspace(-half, half, 21)
    gx, gy = np.meshgrid(xs, ys)
    h = heightmap.height(gx.ravel(), gy.ravel())
    return float(np.ptp(h)) < 1e-6


def standing_mission_start(heightmap, x: float, y: float):
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology
    from qz_drake.scene import standing_state
    from qz_drake.systems.mission_sequencer import measured_start

    state = standing_state(heightmap, get_topology("nominal"), xy=(x, y), yaw=0.0)
    return measured_start(state, 0.0, DEFAULT_PARAMS)


def first_planned(planner, start, target, rungs=("",) + RUNGS):
    """The first rung that plans: (plan or None, rung, reasons)."""
    reasons = []
    for rung in rungs:
        plan, reason = planner(start, target, "nominal", start.time, rung=rung)
        if plan is not None:
            return plan, rung, reasons
        reasons.append(f"{rung or 'first'}: {reason}")
    return None, "", reasons


def sweep_start(planner, heightmap, x: float, y: float) -> dict:
    """One start of the sweep: the lead-in from level ground, then the mission from x."""
    from qz_drake.systems.blc_plan import expected_end

    k = 1
    while not level(heightmap, x - k * MISSION, y):
        k += 1
        if k > 8:
            return {"lead_in": "no level ground within 8 m before the start"}
    start = standing_mission_start(heightmap, x - k * MISSION, y)
    lead_rungs = []
    for j in range(k - 1, -1, -1):
        plan, rung, reasons = first_planned(planner, start, (x - j * MISSION, y, 0.0))
        if plan is None:
            return {"lead_in": f"mission to x = {x - j * MISSION:.2f} refused: " + " | ".join(reasons)}
        lead_rungs.append(rung)
        start = expected_end(plan)
    target = (x + MISSION, y, 0.0)
    row = {"lead_in": "", "lead_in_missions": k, "lead_in_rungs": lead_rungs}
    clock = time.perf_counter()
    plan, reason = planner(start, target, "nominal", start.time, rung="")
    row["first"] = {"success": plan is not None, "reason": reason, "iterations": planner.last_iterations,
                    "wall_s": time.perf_counter() - clock}
    if plan is None:
        row["rungs"] = {}
        for rung in RUNGS:
            clock = time.perf_counter()
            planned, reason = planner(start, target, "nominal", start.time, rung=rung)
            row["rungs"][rung] = {"success": planned is not None, "reason": reason,
                                  "iterations": planner.last_iterations,
                                  "wall_s": time.perf_counter() - clock}
    return row


# BlcParameters fields given with --blc, for every solve and walk of this run.
BLC_CHANGES: dict = {}


def _blc(**fields):
    """The BLC's parameters: ``fields`` and --blc's changes."""
    from qz_drake.trajopt.parameters import BlcParameters

    return BlcParameters(**{**fields, **BLC_CHANGES})


def run(out: Path, world: str, feature: str, y: float | None) -> None:
    from qz_drake.config import MissionTiming
    from qz_drake.experiments.worlds import make_task
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.systems.blc_plan import blc_mission_planner

    terrain, difficulty, seed = world.rsplit("-", 2)
    if 50 <= int(seed) <= 99:
        raise SystemExit(f"--world {world}: seeds 50-99 are kept for checks outside the project")
    task = make_task(terrain, difficulty, int(seed))
    heightmap = task.heightmap
    y = float(task.start[1] if y is None else y)
    y = heightmap.origin[1] + heightmap.resolution * round((y - heightmap.origin[1]) / heightmap.resolution)
    edge = feature_edge(heightmap, y, feature)
    planner = blc_mission_planner(heightmap, DEFAULT_PARAMS, MissionTiming(),
                                  _blc(max_iterations=30, time_limit=30.0))
    done = set()
    if out.exists():
        done = {round(json.loads(line)["offset"], 3) for line in out.read_text().splitlines() if line.strip()}
    with out.open("a") as f:
        for i in range(COUNT):
            offset = round(-BEFORE + i * STEP, 3)
            if offset in done:
                continue
            x = edge + offset
            row = {"world": world, "feature": feature, "y": y, "edge_x": edge, "offset": offset, "x": x,
                   **sweep_start(planner, heightmap, x, y)}
            f.write(json.dumps(row) + "\n")
            f.flush()
            first = row.get("first", {})
            print(f"{world} {feature} {offset:+.1f}: lead-in {row['lead_in'] or 'ok'}; first "
                  f"{first.get('success')}; rungs "
                  f"{ {k: v['success'] for k, v in row.get('rungs', {}).items()} }", flush=True)


def walk_from(task, m, ladder: str, settings) -> dict:
    """The refused mission ``m`` walked in Drake from its recorded stance with the ladder."""
    from qz_drake.config import (ControllerConfig, RobotConfig, Scenario, SimulationConfig, TerrainConfig,
                                 Waypoint)
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology
    from qz_drake.simulation import walk

    b = m["blc_start"]
    x, y, yaw = b["xy_yaw"]
    c, s = math.cos(yaw), math.sin(yaw)
    feet = np.asarray(b["feet"], dtype=float)[:, :2] - [x, y]
    feet_B = feet @ np.array([[c, -s], [s, c]])  # world offsets into the base frame
    offsets = feet_B - get_topology(m["topology"], DEFAULT_PARAMS).footholds_B[:, :2]
    tx, ty, tyaw = m["target"]
    length = math.hypot(tx - x, ty - y) + 0.01
    scenario = Scenario(
        name="refused_mission", terrain=TerrainConfig(kind="flat", region=[x - 3, x + 3, y - 3, y + 3]),
        robot=RobotConfig(topology=m["topology"], initial_xy=[x, y], initial_yaw=yaw,
                          initial_foot_offsets=offsets.tolist()),
        simulation=SimulationConfig(duration=25.0),
        controller=ControllerConfig(kind="walk", planner="blc", mission_length=max(length, 0.3),
                                    speed=settings["speed"], phase_duration=settings["phase_duration"],
                                    route=[Waypoint(x=tx, y=ty, yaw=tyaw, topology=m["topology"])]))
    from qz_drake.errors import QzError

    try:
        result = walk(scenario, heightmap=task.heightmap, stop_on_failure=True, blc_ladder=ladder or None,
                      blc_params=_blc(max_iterations=settings["blc_max_iterations"],
                                      time_limit=settings["blc_time_limit"],
                                      terminal_stance=settings.get("blc_terminal_stance", "free")))
    except QzError as e:  # the stance cannot be stood in from standing (feet on two levels)
        return {"success": False, "reasons": ["stance_not_set_up"], "message": str(e)[:300], "blc_solves": 0}
    metrics = result.metrics
    return {"success": bool(metrics["success"]), "reasons": list(metrics.get("reasons", [])),
            "message": str(metrics.get("reason", ""))[:300], "blc_solves": int(metrics.get("blc_solves", 0))}


def replay(out: Path, runs, walk_ladder: str | None = None) -> None:
    """The refused missions of recorded walks, solved again from their recorded BLC start."""
    from qz_drake.config import MissionTiming
    from qz_drake.experiments.worlds import make_task
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.systems.blc_plan import blc_mission_planner
    from qz_drake.systems.mission_sequencer import MissionStart

    done = set()
    if out.exists():
        done = {json.loads(line)["id"] for line in out.read_text().splitlines() if line.strip()}
    refused = []
    for run in runs:
        for results in sorted(Path(run).rglob("results.jsonl")):
            settings = json.loads((results.parent / "settings.json").read_text())
            for line in results.read_text().splitlines():
                record = json.loads(line)
                if 50 <= int(record["seed"]) <= 99:
                    raise SystemExit(f"{results}: a world of seed {record['seed']} (kept for checks outside the project)")
                for k, m in enumerate(record.get("mission_records") or []):
                    if m["outcome"] == "no_plan" and m.get("blc_start"):
                        refused.append((f"{results.parent}:{record['key']}:{k}", record, settings, m))
    with out.open("a") as f:
        for key, record, settings, m in refused:
            if key in done:
                continue
            task = make_task(record["terrain"], record["difficulty"], int(record["seed"]))
            timing = MissionTiming(speed=settings["speed"], phase_duration=settings["phase_duration"])
            planner = blc_mission_planner(task.heightmap, DEFAULT_PARAMS, timing, _blc(
                max_iterations=settings["blc_max_iterations"], time_limit=settings["blc_time_limit"],
                terminal_stance=settings.get("blc_terminal_stance", "free")))
            b = m["blc_start"]
            base_z = None if b["base_z"] is None or math.isnan(b["base_z"]) else b["base_z"]  # NaN: unknown
            start = MissionStart(time=0.0, xy_yaw=tuple(b["xy_yaw"]), feet_W=np.array(b["feet"]),
                                 base_z=base_z, roll_pitch=tuple(b["roll_pitch"]))
            row = {"id": key, "world": f"{record['terrain']}-{record['difficulty']}-{record['seed']}",
                   "planner": record["planner"], "topology": m["topology"], "target": m["target"],
                   "start": b["xy_yaw"], "recorded": m["message"], "lead_in": ""}
            clock = time.perf_counter()
            plan, reason = planner(start, tuple(m["target"]), m["topology"], 0.0, rung="")
            row["first"] = {"success": plan is not None, "reason": reason, "iterations": planner.last_iterations,
                            "wall_s": time.perf_counter() - clock}
            row["rungs"] = {}
            for rung in RUNGS:
                clock = time.perf_counter()
                planned, reason = planner(start, tuple(m["target"]), m["topology"], 0.0, rung=rung)
                row["rungs"][rung] = {"success": planned is not None, "reason": reason,
                                      "iterations": planner.last_iterations, "wall_s": time.perf_counter() - clock}
            if walk_ladder is not None:
                row["walk"] = {"ladder": walk_ladder, **walk_from(task, m, walk_ladder, settings)}
            f.write(json.dumps(row) + "\n")
            f.flush()
            print(f"{key}: first {row['first']['success']}; rungs "
                  f"{ {k: v['success'] for k, v in row['rungs'].items()} }; walk "
                  f"{row.get('walk', {}).get('success')} {row.get('walk', {}).get('message', '')[:100]}", flush=True)


def summary(paths) -> None:
    """Per file: starts, lead-ins refused, first solves planned, and what each ladder order
    would plan (rungs tried in order until one plans) with its median and worst extra time."""
    ladders = [("cycles+1",), ("cycles+1", "cycles+2"), ("split",), ("cycles+1", "split"),
               ("cycles+1", "split", "cycles+2", "split+1"), ("cycles+1", "cycles+2", "short"),
               ("cycles+1", "short", "cycles+2", "split")]
    print("| sweep | starts | lead-in refused | first solves planned | "
          + " | ".join(f"ladder {', '.join(ladder)}" for ladder in ladders) + " |")
    print("| --- " * (4 + len(ladders)) + "|")
    for path in paths:
        rows = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
        # A walk's refusal for its wall-time limit is the loaded machine's, not the BLC's: left out.
        rows = [r for r in rows if "Wall time exceeded; time limit" not in r.get("recorded", "")]
        measured = [r for r in rows if not r["lead_in"]]
        first = sum(r["first"]["success"] for r in measured)
        cells = []
        for ladder in ladders:
            planned, extra = first, []
            for r in measured:
                if r["first"]["success"]:
                    continue
                cost = 0.0
                for rung in ladder:
                    if rung not in r["rungs"]:
                        cost = math.nan  # a row measured before the rung existed
                        break
                    cost += r["rungs"][rung]["wall_s"]
                    if r["rungs"][rung]["success"]:
                        planned += 1
                        break
                extra.append(cost)
            if any(math.isnan(c) for c in extra):
                cells.append("-")
                continue
            times = f"{np.median(extra):.1f} / {max(extra):.1f} s" if extra else "-"
            cells.append(f"{planned} ({times})")
        if rows and "feature" in rows[0]:
            name = f"{rows[0]['world']} {rows[0]['feature']} y={rows[0]['y']:.2f}"
        else:
            name = f"refused missions of {path}"
        print(f"| {name} | {len(rows)} | {len(rows) - len(measured)} | {first} | " + " | ".join(cells) + " |")
    for path in paths:
        rows = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
        walked = [r for r in rows if "walk" in r and "Wall time exceeded; time limit" not in r["recorded"]]
        if walked:
            reasons = {}
            for r in walked:
                if not r["walk"]["success"]:
                    key = (r["walk"]["reasons"] or ["?"])[0]
                    reasons[key] = reasons.get(key, 0) + 1
            print(f"\n{path}: walked in Drake from the recorded stance with the ladder "
                  f"{walked[0]['walk']['ladder']}: {sum(r['walk']['success'] for r in walked)} of {len(walked)}"
                  + (" (failures: " + ", ".join(f"{k} {v}" for k, v in sorted(reasons.items())) + ")" if reasons else ""))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="+", type=Path)
    parser.add_argument("--world", default="stairs-hard-3")
    parser.add_argument("--feature", choices=("up", "down"), default="up")
    parser.add_argument("--y", type=float, default=None, help="the row (default: the task's start y)")
    parser.add_argument("--summary", action="store_true", help="print the table of the files given")
    parser.add_argument("--replay", nargs="+", type=Path, default=None,
                        help="results folders of walks with recorded missions: their refused missions")
    parser.add_argument("--walk", default=None, metavar="LADDER",
                        help="with --replay: walk each refused mission in Drake from its stance with this ladder")
    parser.add_argument("--blc", action="append", default=[], metavar="NAME=VALUE",
                        help="a BlcParameters field for every solve and walk (value as JSON; repeatable)")
    args = parser.parse_args(argv)
    from tree_runs import blc_changes

    BLC_CHANGES.update(blc_changes(args.blc, "--blc"))
    if args.summary:
        summary(args.out)
        return 0
    if len(args.out) != 1:
        parser.error("one OUT file for a sweep or a replay")
    if args.replay:
        replay(args.out[0], args.replay, args.walk)
    else:
        run(args.out[0], args.world, args.feature, args.y)
    return 0


if __name__ == "__main__":
    sys.exit(main())
