"""The comparison of paper 000 Fig. 9: top-level controllers on the same BLC, executed in Drake.

"They share the same BLC of CapPlanner, but different TLC." A task is walked by its planner's
route (``PLANNERS``), in BLC missions of at most 1 m, tracked by IK and joint PD, judged by the
strict verdict, within a simulated-time budget; the record holds success, reason, walked path
length, straight-line distance, displacement ratio (walked / straight), missions, replans,
topology changes and wall time. Results are appended to ``results.jsonl`` as tasks finish (one
writer: the driver), so a run resumes where it stopped and never runs a task twice.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from qz_drake.config import MissionTiming
from qz_drake.errors import bad_value
from qz_drake.progress import ProgressReport
from qz_drake.state_layout import BASE_XY
from qz_drake.experiments.worlds import DIFFICULTIES, PLANNER_NAMES, TERRAINS, TASKS_PER_CELL, make_task

RESULTS = "results.jsonl"
# Most tasks per terrain and difficulty one run may plan: 20 times the experiment's.
MAX_TASKS_PER_CELL = 20 * TASKS_PER_CELL
# Most BLC retries of a mission: each one is another solve of up to blc_time_limit seconds.
MAX_BLC_RETRIES = 10
# settings.json's record of the capability model CapPlanner's walks used (CapabilityModel.identity).
MODEL_IDENTITY = "capability_model_identity"


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """Settings shared by every task of a run (part of each record)."""

    # Mission length, speed and tripod phase of the BLC missions. [m], [m/s], [s]
    mission_length: float = 1.0
    speed: float = MissionTiming.speed
    phase_duration: float = MissionTiming.phase_duration
    # Simulated-time budget: this many times the straight-line walking time, plus a margin. [-], [s]
    time_factor: float = 2.5
    time_margin: float = 20.0
    # The BLC's budget per mission (as the capability trials: deterministic). [iterations], [s]
    blc_max_iterations: int = 30
    blc_time_limit: float = 30.0
    # How often a mission the BLC could not plan is solved again, one tripod cycle longer each
    # time, for both planners alike (TrajectoryOptimizationBLC's mission_retries), before the
    # planner's recovery hears of the refusal. 0: first solves only, the capability trials' BLC.
    # Of 9 refusals in CapPlanner's walks of three hard tuning worlds, one tripod cycle longer
    # planned 4, the same mission with 200 Ipopt iterations instead of 30 none (BENCHMARKS
    # "fig9", session 40).
    blc_retries: int = 0
    # The BLC ladder instead (TrajectoryOptimizationBLC's ``ladder``, e.g. "cycles+1,split"), for
    # both planners alike; "": the retries'. Not with blc_retries.
    blc_ladder: str = ""
    # CapPlanner's capability model folder; empty: the shipped one.
    capability_model: str = ""
    # World scale (1: the experiment; smaller: tiny tasks for tests, see worlds.make_task).
    scale: float = 1.0
    # The A* baseline's thresholds and safety weight (astar_baseline.AStarBaselineConfig),
    # chosen by ``qz experiment tune-astar`` on worlds that are not the experiment's.
    astar_max_step_height: float = 0.2
    astar_max_slope_deg: float = 30.0
    astar_safety_weight: float = 0.5
    astar_body_radius: float = 0.7
    # Missions the BLC could not plan that A* goes round (experiments/astar_recovery.py, issue
    # 38): the same number CapPlanner's TLC does (4); 0: A* stops at the first (the first
    # Fig. 9 run's baseline).
    astar_max_recoveries: int = 4
    # Both planners back out of a dead end, a stance from which going round finds no way on
    # (qz_drake.planning.back_out, session 38); False: as before.
    recovery_back_out: bool = True
    # CapPlanner's risk and topology-change settings (capability_mdp.CapabilityMdpConfig's
    # failure_reward and topology_change_cost), chosen by ``qz experiment tune-capplanner`` on
    # the same tuning worlds as A*'s.
    capplanner_failure_reward: float = -100.0
    capplanner_topology_change_cost: float = 2.0
    # The share of predicted planning failures CapPlanner counts as falls
    # (capability_mdp.CapabilityMdpConfig.plan_failure_risk).
    capplanner_plan_failure_risk: float = 0.0
    # Whether CapPlanner doubts a topology change by the ensemble's disagreement about the
    # difference between the topologies (capability_mdp.CapabilityMdpConfig.topology_doubt).
    capplanner_topology_doubt: bool = True
    # Whether CapPlanner judges the first moves of each replan from the stance the robot stands
    # in, and backs out of a dead end the model foretells (CapabilityVIPlanner's measured_stance).
    capplanner_measured_stance: bool = True
    # Whether a move the BLC refused is closed in every topology from that cell and heading
    # (CapabilityVIPlanner's refused_in_every_topology, session 39); False: CapPlanner may
    # try it again in another topology.
    capplanner_refused_in_every_topology: bool = True
    # CapPlanner's split of its path into BLC missions (guidance.MissionSplitConfig): the
    # longest mission [m] and the least predicted success of a merged mission.
    capplanner_mission_length: float = 2.0
    capplanner_merge_min_success: float = 0.8
    # The least predicted chance of arriving without a fall for which CapPlanner sets out
    # (CapabilityVIPlanner's min_route_success). 0: it never declines a task it has a path for,
    # as A* never declines one it has a route for; a declined task is a failed one here.
    capplanner_min_route_success: float = 0.0
    # Keep every mission of every walk in its record (``missions``: where it started, its
    # target, its outcome; capability.walk_missions), for scoring a capability model on whole
    # walks (issue 37). Off for the experiment itself (the records stay small).
    record_missions: bool = False


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    terrain: str
    difficulty: str
    seed: int
    planner: str
    # A folder for the walk's recording (recording.html, metrics.json, plots); empty: none.
    record_dir: str = ""

    @property
    def key(self) -> str:
        return f"{self.terrain}-{self.difficulty}-{self.seed}-{self.planner}"


def _astar(task, config):
    """A* over the geometric cost map: a route in the nominal topology (planner blc), walked
    with the recovery of experiments/astar_recovery.py (``astar_max_recoveries``)."""
    import time

    from qz_drake.experiments.astar_baseline import AStarBaseline, AStarBaselineConfig
    from qz_drake.experiments.astar_recovery import AStarRoute

    clock = time.perf_counter()
    baseline = AStarBaseline(task.heightmap, AStarBaselineConfig(max_step_height=config.astar_max_step_height,
                                                                 max_slope_deg=config.astar_max_slope_deg,
                                                                 safety_weight=config.astar_safety_weight,
                                                                 body_radius=config.astar_body_radius,
                                                                 waypoint_spacing=config.mission_length))
    route = baseline.route(task.start, task.goal)
    route = dataclasses.replace(route, planning_time_s=time.perf_counter() - clock)
    return route, "blc", route.waypoints, AStarRoute(baseline, task.goal, config.astar_max_recoveries,
                                                     back_out=config.recovery_back_out)


def _capplanner(task, config):
    """CapPlanner's TLC in the diagram (planner capplanner): the goal is the only waypoint."""
    from qz_drake.experiments.astar_baseline import Route
    from qz_drake.planning.capplanner_route import CapPlannerRoute
    from qz_drake.planning.guidance import MissionSplitConfig

    split = MissionSplitConfig(max_length=config.capplanner_mission_length,
                               min_success=config.capplanner_merge_min_success)
    return (Route(True, "", [], 0.0, np.zeros((0, 2))), "capplanner", [(*task.goal, 0.0, "nominal")],
            CapPlannerRoute(split, min_route_success=config.capplanner_min_route_success,
                            back_out=config.recovery_back_out, measured_stance=config.capplanner_measured_stance,
                            refused_in_every_topology=config.capplanner_refused_in_every_topology))


def _mdp_overrides(config: ExperimentConfig) -> dict:
    """CapPlanner's MDP settings of a run (scenario.controller.capability_mdp)."""
    return dict(failure_reward=config.capplanner_failure_reward,
                topology_change_cost=config.capplanner_topology_change_cost,
                plan_failure_risk=config.capplanner_plan_failure_risk,
                topology_doubt=float(config.capplanner_topology_doubt))


# Top-level controllers: name -> (task, config) -> (Route, walking planner, waypoints, route
# source of the walk or None: the scenario's own, qz_drake.planning.capplanner_route.route_source_for).
PLANNERS = {"astar": _astar, "capplanner": _capplanner}


def run_task(spec: TaskSpec, config: ExperimentConfig = ExperimentConfig()) -> dict:
    """Plans and walks one task; returns its record (never raises for a failed walk)."""
    from qz_drake.config import (ControllerConfig, RobotConfig, Scenario, SimulationConfig,
                                 TerrainConfig, Waypoint)
    from qz_drake.planning.capplanner_route import route_source_for
    from qz_drake.simulation import walk
    from qz_drake.trajopt.parameters import BlcParameters

    clock = time.perf_counter()
    task = make_task(spec.terrain, spec.difficulty, spec.seed, scale=config.scale)
    record = {"key": spec.key, "terrain": spec.terrain, "difficulty": spec.difficulty, "seed": spec.seed,
              "planner": spec.planner, "straight_m": task.distance, "success": False, "reason": "",
              "message": "", "walked_m": 0.0, "displacement_ratio": None, "missions": 0, "replans": 0,
              "recoveries": 0, "back_outs": 0, "topology_changes": 0, "planning_time_s": 0.0, "wall_time_s": 0.0,
              "error": ""}
    try:
        route, walking_planner, waypoints, route_source = PLANNERS[spec.planner](task, config)
        record["planning_time_s"] = route.planning_time_s
        if not route.found:
            record.update(reason="planner", message=route.reason)
            return record
        # Both planners walk on the whole world (CapPlanner may detour anywhere on it).
        xmin, xmax, ymin, ymax = task.heightmap.bounds
        region = [xmin, xmax, ymin, ymax]
        budget = config.time_factor * task.distance / config.speed + config.time_margin
        scenario = Scenario(
            name=spec.key, terrain=TerrainConfig(kind="flat", region=region),
            robot=RobotConfig(initial_xy=list(task.start), initial_yaw=task.start_yaw),
            simulation=SimulationConfig(duration=budget),
            controller=ControllerConfig(kind="walk", planner=walking_planner, mission_length=config.mission_length,
                                        speed=config.speed, phase_duration=config.phase_duration,
                                        capability_model=config.capability_model,
                                        capability_mdp=_mdp_overrides(config),
                                        route=[Waypoint(x=x, y=y, yaw=a, topology=t) for x, y, a, t in waypoints]))
        # One BLC for both planners, as paper 000 has it: first solves only (the trials' BLC, and
        # the one the A* settings were tuned with) unless ``blc_retries`` says otherwise, the
        # same for both; what differs is the TLC, including how it goes round a mission the BLC
        # could not plan.
        if config.record_missions:  # a walk that never started (its first mission refused) keeps none
            record["mission_records"] = []

        def keep_missions(built, run, judged):
            from qz_drake.capability.walk_missions import walk_mission_records

            record["mission_records"] = walk_mission_records(built, run, judged, scenario.success)

        result = walk(scenario, heightmap=task.heightmap, stop_on_failure=True,
                      out_dir=spec.record_dir or None, mission_retries=config.blc_retries,
                      blc_ladder=config.blc_ladder or None,
                      route_source=route_source or route_source_for(scenario),
                      on_judged=keep_missions if config.record_missions else None,
                      blc_params=BlcParameters(max_iterations=config.blc_max_iterations,
                                               time_limit=config.blc_time_limit))
        m = result.metrics
        walked = float(np.sum(np.linalg.norm(np.diff(result.states[:, BASE_XY], axis=0), axis=1))) \
            if len(result.states) > 1 else 0.0
        record.update(success=bool(m["success"]), reason=(m.get("reasons") or [""])[0],
                      message=str(m.get("reason", ""))[:300], walked_m=walked,
                      path_xy=path_samples(result.states[:, BASE_XY]),
                      displacement_ratio=walked / task.distance if m["success"] else None,
                      missions=int(m.get("missions", 0)), topology_changes=int(m.get("topology_changes", 0)),
                      replans=int(m.get("replans", 0)), recoveries=int(m.get("tlc_recoveries", 0)),
                      # Ways back out of a dead end (qz_drake.planning.back_out).
                      back_outs=int(m.get("tlc_back_outs", 0)))
        if spec.planner == "capplanner":
            record["planning_time_s"] = float(m.get("planning_time_s", 0.0))
            # Replans that walked the most probable path (the MDP's policy did not reach the goal).
            record["most_probable"] = int(m.get("tlc_most_probable", 0))
    except Exception as e:  # a crash of the run, not an outcome: recorded as an error
        import traceback

        record.update(reason="error", error=f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}"[-600:])
    finally:
        record["wall_time_s"] = time.perf_counter() - clock
    return record


# Spacing of the walked path kept in each record (path_samples). [m]
PATH_SPACING = 0.25


def path_samples(xy, spacing: float = PATH_SPACING) -> list:
    """The base's path [(x, y), ...] [m] at about ``spacing`` along it: the first point, every
    point where the distance walked passes a multiple of ``spacing``, and the last (where a
    failed walk stopped), to the centimetre; a 15 m walk keeps about 60 points."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(xy) == 0:
        return []
    walked = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    steps = np.floor(walked / spacing)
    keep = np.flatnonzero(np.concatenate([[True], steps[1:] != steps[:-1]]))
    if keep[-1] != len(xy) - 1:
        keep = np.append(keep, len(xy) - 1)
    return np.round(xy[keep], 2).tolist()


def discordant_tasks(records: list[dict], planner: str = "capplanner", baseline: str = "astar") -> list[dict]:
    """The tasks one planner walked and the other did not (errors left out): per task its key
    (without the planner), terrain, difficulty, seed, who walked it, and both records."""
    by_task: dict[tuple, dict] = {}
    for r in records:
        if r.get("reason") != "error" and r["planner"] in (planner, baseline):
            by_task.setdefault((r["terrain"], r["difficulty"], r["seed"]), {})[r["planner"]] = r
    out = []
    for (terrain, difficulty, seed), pair in sorted(by_task.items(), key=lambda kv: (
            TERRAINS.index(kv[0][0]) if kv[0][0] in TERRAINS else 99,
            DIFFICULTIES.index(kv[0][1]) if kv[0][1] in DIFFICULTIES else 99, kv[0][2])):
        if len(pair) == 2 and pair[planner]["success"] != pair[baseline]["success"]:
            winner = planner if pair[planner]["success"] else baseline
            out.append({"task": f"{terrain}-{difficulty}-{seed}", "terrain": terrain, "difficulty": difficulty,
                        "seed": seed, "walked": winner, "failed": baseline if winner == planner else planner,
                        "records": pair})
    return out


def discordant_pictures(out, folder=None, scale: float | None = None) -> list[dict]:
    """For every discordant task of a results folder, a PNG of its world with both walked
    paths, the start, the goal and where the failed walk stopped with its reason
    (``folder``, default ``out/discordant``). Returns the tasks (discordant_tasks) with the
    picture's path in ``picture``. Walks recorded before paths were kept draw without one."""
    from qz_drake.experiments.plots import plot_task_pair

    out = Path(out)
    records = read_results(out)
    folder = Path(folder) if folder is not None else out / "discordant"
    scale = float(_settings(out).get("scale", 1.0)) if scale is None else float(scale)
    tasks = discordant_tasks(records)
    for t in tasks:
        task = make_task(t["terrain"], t["difficulty"], t["seed"], scale=scale)
        t["picture"] = str(plot_task_pair(task, t["records"], folder / f"{t['task']}.png", title=t["task"]))
    return tasks


def _crashed(spec: TaskSpec, message: str, config) -> dict:
    return {"key": spec.key, "terrain": spec.terrain, "difficulty": spec.difficulty, "seed": spec.seed,
            "planner": spec.planner, "success": False, "reason": "error", "error": message}


def read_results(out) -> list[dict]:
    path = Path(out) / RESULTS
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def summarise(records: list[dict]) -> list[dict]:
    """Per terrain, difficulty and planner: tasks, successes, success rate and the mean
    displacement ratio of the successful tasks (errors are counted apart, not as tasks)."""
    rows = []
    for terrain in TERRAINS:
        for difficulty in DIFFICULTIES:
            for planner in sorted({r["planner"] for r in records}):
                cell = [r for r in records if (r["terrain"], r["difficulty"], r["planner"]) == (terrain, difficulty, planner)]
                done = [r for r in cell if r["reason"] != "error"]
                if not cell:
                    continue
                ok = [r for r in done if r["success"]]
                rows.append({"terrain": terrain, "difficulty": difficulty, "planner": planner,
                             "tasks": len(done), "successes": len(ok), "errors": len(cell) - len(done),
                             "success_rate": len(ok) / len(done) if done else None,
                             "displacement_ratio": float(np.mean([r["displacement_ratio"] for r in ok])) if ok else None})
    return rows


def compare_planners(records: list[dict], planner: str = "capplanner", baseline: str = "astar") -> list[dict]:
    """The paper's claim, cell by cell: ``planner`` against ``baseline`` on the same tasks.

    Both planners walk the same worlds (a task is a terrain, difficulty and seed), so the test
    is paired: of the tasks both finished (errors left out), how many both walked, only one of
    them walked, neither; and McNemar's exact test (a two-sided binomial test of the discordant
    tasks, scipy.stats.binomtest) of "the two succeed equally often". One row per (terrain,
    difficulty), then one per difficulty over the terrains and one over all."""
    from qz_drake.capability.evaluation import mcnemar_exact_p

    outcome = {}
    for r in records:
        if r.get("reason") != "error" and r["planner"] in (planner, baseline):
            outcome[(r["terrain"], r["difficulty"], r["seed"], r["planner"])] = bool(r["success"])
    paired = {(t, d, s): (outcome[(t, d, s, planner)], outcome[(t, d, s, baseline)])
              for (t, d, s, p) in outcome if p == planner and (t, d, s, baseline) in outcome}

    def row(terrain, difficulty, keys):
        pairs = [paired[k] for k in keys]
        only_planner = sum(a and not b for a, b in pairs)
        only_baseline = sum(b and not a for a, b in pairs)
        return {"terrain": terrain, "difficulty": difficulty, "tasks": len(pairs),
                f"{planner}_successes": sum(a for a, _ in pairs), f"{baseline}_successes": sum(b for _, b in pairs),
                "both": sum(a and b for a, b in pairs), f"only_{planner}": only_planner,
                f"only_{baseline}": only_baseline, "neither": sum(not a and not b for a, b in pairs),
                "p_value": mcnemar_exact_p(only_planner, only_baseline)}

    rows = []
    for terrain in TERRAINS:
        for difficulty in DIFFICULTIES:
            keys = [k for k in paired if k[:2] == (terrain, difficulty)]
            if keys:
                rows.append(row(terrain, difficulty, keys))
    for difficulty in DIFFICULTIES:
        keys = [k for k in paired if k[1] == difficulty]
        if keys:
            rows.append(row("all", difficulty, keys))
    if paired:
        rows.append(row("all", "all", list(paired)))
    return rows


# The aim issue 38 states for the decisive run (paper 000's claim, made testable): CapPlanner
# at least CLAIM_DIFFERENCE above A* on medium + hard together with McNemar's exact p below
# CLAIM_ALPHA, and CapPlanner's own success at least CLAIM_RATES per difficulty.
CLAIM_DIFFERENCE = 0.10
CLAIM_ALPHA = 0.01
CLAIM_RATES = {"medium": 0.80, "hard": 0.40}
CLAIM_DIFFICULTIES = ("medium", "hard")
# Power wanted to detect CLAIM_DIFFERENCE at CLAIM_ALPHA.
CLAIM_POWER = 0.8


def claim_check(records: list[dict]) -> dict | None:
    """The aim, checked on a run: on medium + hard pooled (paired tasks), both planners'
    success, the difference with its 95 % Wald interval for paired proportions, McNemar's exact
    p; CapPlanner's rate per difficulty against CLAIM_RATES; whether each part holds; and the
    design's power: the share of discordant tasks, the power of this many paired tasks to find
    CLAIM_DIFFERENCE at CLAIM_ALPHA, and the tasks per cell that would give CLAIM_POWER."""
    from qz_drake.capability.evaluation import mcnemar_exact_p, mcnemar_power, pairs_for_power

    rows = {(c["terrain"], c["difficulty"]): c for c in compare_planners(records)}
    cells = [c for (t, d), c in rows.items() if t != "all" and d in CLAIM_DIFFICULTIES]
    n = sum(c["tasks"] for c in cells)
    if not n:
        return None
    b = sum(c["only_capplanner"] for c in cells)
    c_ = sum(c["only_astar"] for c in cells)
    cap = sum(c["capplanner_successes"] for c in cells) / n
    astar = sum(c["astar_successes"] for c in cells) / n
    difference = (b - c_) / n
    half = 1.96 * np.sqrt(max((b + c_) - (b - c_) ** 2 / n, 0.0)) / n
    p = mcnemar_exact_p(b, c_)
    rates = {d: (rows[("all", d)]["capplanner_successes"] / rows[("all", d)]["tasks"]) if ("all", d) in rows else None
             for d in CLAIM_RATES}
    discordant = (b + c_) / n
    per_cell = len(cells)
    needed = (pairs_for_power(discordant, CLAIM_DIFFERENCE, alpha=CLAIM_ALPHA, power=CLAIM_POWER)
              if discordant >= CLAIM_DIFFERENCE else None)
    return {"tasks": n, "capplanner_rate": cap, "astar_rate": astar, "difference": difference,
            "difference_ci95": [difference - half, difference + half], "only_capplanner": b, "only_astar": c_,
            "p_value": p, "difference_holds": bool(difference >= CLAIM_DIFFERENCE and p < CLAIM_ALPHA),
            "capplanner_rates": rates,
            "rates_hold": {d: (r is not None and r >= CLAIM_RATES[d]) for d, r in rates.items()},
            "discordant_share": discordant,
            "power": (mcnemar_power(n, discordant, CLAIM_DIFFERENCE, CLAIM_ALPHA)
                      if discordant >= CLAIM_DIFFERENCE else None),
            "tasks_per_cell_for_power": None if needed is None else int(np.ceil(needed / per_cell))}


def compare_runs(records: list[dict], other: list[dict], planners=None) -> list[dict]:
    """Each planner against itself in another run of the same tasks (another capability model,
    BLC or tuning): paired by task as :func:`compare_planners`, with McNemar's exact test of
    "the two runs succeed equally often". Rows carry ``planner``; ``this_successes`` /
    ``other_successes``, ``only_this`` / ``only_other`` count the run given first / second."""
    if planners is None:
        planners = sorted({r["planner"] for r in records} & {r["planner"] for r in other})
    rows = []
    for planner in planners:
        pooled = [dict(r, planner="this") for r in records if r["planner"] == planner]
        pooled += [dict(r, planner="other") for r in other if r["planner"] == planner]
        rows += [{"planner": planner, **row} for row in compare_planners(pooled, planner="this", baseline="other")]
    return rows


# Walks a local worker process makes before a fresh one takes its place: every walk's diagram
# stays in the process that built it (LocalPool), about 200 MB a full-size walk; with 20 the
# decisive run's workers held at most 3.0 GB, and a fresh worker's start (a few seconds) is small
# beside 20 walks (15-30 minutes).
WALKS_PER_WORKER = 20


# Settings whose coming changed what the walks do, with the value that results written before
# them were walked with: a folder without the setting holds those walks, not today's default's.
# A* had no recovery before issue 38; CapPlanner declined paths whose predicted chance of no
# fall was below 0.05 (CapabilityVIPlanner's default).
SETTINGS_BEFORE_THEY_EXISTED = {"astar_max_recoveries": 0, "capplanner_min_route_success": 0.05,
                                "recovery_back_out": False, "capplanner_topology_doubt": False,
                                "capplanner_measured_stance": False, "capplanner_refused_in_every_topology": False,
                                "blc_ladder": ""}


def _settings(out: Path) -> dict:
    """The settings a results folder's walks had ({} without settings.json)."""
    path = out / "settings.json"
    return {**SETTINGS_BEFORE_THEY_EXISTED, **json.loads(path.read_text())} if path.is_file() else {}


def _against(out: Path, records: list[dict], against) -> dict:
    """The comparison of a results folder with another one (``report(..., against=)``)."""
    against = Path(against)
    if not (against / RESULTS).is_file():
        raise bad_value("against", str(against), f"no {RESULTS} there (run qz experiment capplanner-vs-astar)")
    mine, theirs = _settings(out), _settings(against)
    scales = (float(mine.get("scale", 1.0)), float(theirs.get("scale", 1.0)))
    if scales[0] != scales[1]:
        raise bad_value("against", str(against), f"its worlds are at scale {scales[1]:g} and this run's at "
                        f"{scales[0]:g}: not the same tasks")
    changed = {k: [mine.get(k), theirs.get(k)] for k in sorted(set(mine) | set(theirs)) if mine.get(k) != theirs.get(k)}
    return {"folder": str(against), "changed_settings": changed,
            "comparisons": compare_runs(records, read_results(against))}


PREDICTIONS = "predictions.jsonl"


def predict_route(spec: TaskSpec, config: ExperimentConfig = ExperimentConfig(), model=None) -> dict:
    """What CapPlanner's model expected of a task before walking it: the plan from the start
    (the walk's first plan: same model, MDP settings, start cell and heading), its predicted
    chance that no action ends the walk (fall_free), the product of the actions' success
    (success), the actions and topology changes; reaches False where it found no path."""
    from qz_drake.capability.model import CapabilityModel
    from qz_drake.capability.patches import KINDS
    from qz_drake.planning.capability_mdp import plan
    from qz_drake.robot.topology import TOPOLOGY_NAMES
    from qz_drake.planning.capplanner_route import mdp_config

    model = model or CapabilityModel.load(config.capability_model or None)
    task = make_task(spec.terrain, spec.difficulty, spec.seed, scale=config.scale)
    topologies = [t for t in TOPOLOGY_NAMES if all(model.has_network(t, k) for k in KINDS)]
    mdp = mdp_config(_mdp_overrides(config), topologies)
    heading = int(round(task.start_yaw / (np.pi / 4))) % 8
    result = plan(model, task.heightmap, task.start, heading, task.goal, config=mdp)
    return {"key": spec.key, "terrain": spec.terrain, "difficulty": spec.difficulty, "seed": spec.seed,
            "reaches": bool(result.reaches_goal),
            "fall_free": result.fall_free_probability if result.reaches_goal else 0.0,
            "success": result.success_probability if result.reaches_goal else 0.0,
            "actions": len(result.steps), "topology_changes": result.topology_changes}


def predict_routes(out, config: ExperimentConfig | None = None, model=None, progress: bool = False) -> list[dict]:
    """:func:`predict_route` for every CapPlanner task of a results folder, appended to
    ``predictions.jsonl`` (resumable: a task already predicted is skipped); returns them all.
    The config is the run's (settings.json) unless given."""
    from qz_drake.capability.model import CapabilityModel

    out = Path(out)
    if not (out / RESULTS).is_file():
        raise bad_value("results", str(out), f"no {RESULTS} there (run qz experiment capplanner-vs-astar)")
    records = [r for r in read_results(out) if r["planner"] == "capplanner" and r["reason"] != "error"]
    if config is None:
        settings = _settings(out)
        names = {f.name for f in dataclasses.fields(ExperimentConfig)}
        config = ExperimentConfig(**{k: v for k, v in settings.items() if k in names})
        identity = settings.get(MODEL_IDENTITY)
    else:
        identity = None
    model = model or CapabilityModel.load(config.capability_model or None)
    if identity and model.identity != identity:
        raise bad_value("capability model", model.identity,
                        f"the run at {out} walked with model {identity}; predict with that one")
    path = out / PREDICTIONS
    done = {p["key"]: p for p in (json.loads(line) for line in path.read_text().splitlines() if line.strip())} \
        if path.is_file() else {}
    todo = [r for r in records if r["key"] not in done]
    with path.open("a") as f, ProgressReport("predicting routes", len(records), unit="routes",
                                             completed=len(records) - len(todo), enabled=progress) as report:
        for r in todo:
            p = predict_route(TaskSpec(r["terrain"], r["difficulty"], r["seed"], "capplanner"), config, model)
            done[p["key"]] = p
            f.write(json.dumps(p) + "\n")
            f.flush()
            report.update(advance=1)
    return [done[r["key"]] for r in records if r["key"] in done]


def route_calibration(records: list[dict], predictions: list[dict]) -> list[dict]:
    """CapPlanner's route-level calibration per (terrain, difficulty), then per difficulty and
    over all: of the tasks it set out on (a path found), the mean predicted chance of no fall
    along the first plan (and the mean product of its actions' success, counting a planning
    failure as a failure too) against the share walked to the goal, and the share of tasks it
    declined (no path: the goal predicted unreachable) with how many of those A* walked."""
    walked = {r["key"]: bool(r["success"]) for r in records if r["reason"] != "error"}
    astar = {(r["terrain"], r["difficulty"], r["seed"]): bool(r["success"])
             for r in records if r["planner"] == "astar" and r["reason"] != "error"}
    usable = [p for p in predictions if p["key"] in walked]

    def row(terrain, difficulty, cell):
        started = [p for p in cell if p["reaches"]]
        declined = [p for p in cell if not p["reaches"]]
        return {"terrain": terrain, "difficulty": difficulty, "tasks": len(cell), "started": len(started),
                "predicted_fall_free": float(np.mean([p["fall_free"] for p in started])) if started else None,
                "predicted_success": float(np.mean([p["success"] for p in started])) if started else None,
                "walked_rate": float(np.mean([walked[p["key"]] for p in started])) if started else None,
                "declined": len(declined),
                "declined_walked_by_astar": sum(astar.get((p["terrain"], p["difficulty"], p["seed"]), False)
                                                for p in declined)}

    rows = [row(t, d, [p for p in usable if (p["terrain"], p["difficulty"]) == (t, d)])
            for t in TERRAINS for d in DIFFICULTIES]
    rows += [row("all", d, [p for p in usable if p["difficulty"] == d]) for d in DIFFICULTIES]
    rows.append(row("all", "all", usable))
    return [r for r in rows if r["tasks"]]


def planner_differences(settings: dict) -> list[str]:
    """What still differs between the two planners' walks of a run with these settings
    (``settings.json``; {} for defaults), beyond the top-level controller itself: the issue
    asks the report to state every difference, and the settings say which hold."""
    from qz_drake.experiments.astar_recovery import MAX_RECOVERIES

    c = {**dataclasses.asdict(ExperimentConfig()), **SETTINGS_BEFORE_THEY_EXISTED, **settings} if settings else \
        dataclasses.asdict(ExperimentConfig())
    retries = int(c["blc_retries"])
    retry = ("no retry" if not retries else
             f"a refused mission solved again up to {retries} time{'s' if retries > 1 else ''}, one tripod cycle "
             "longer each time")
    if c.get("blc_ladder"):
        retry = f"a refused mission solved again on the ladder {c['blc_ladder']}"
    out = [f"Shared: the BLC ({c['blc_max_iterations']} Ipopt iterations a mission, {retry}), the IK tracker "
           f"and joint PD, the strict verdict, the time budget ({c['time_factor']:g} x the straight-line walking "
           f"time + {c['time_margin']:g} s), the speed and tripod phase."]
    if c["astar_max_recoveries"] == MAX_RECOVERIES:
        out.append(f"Both go round up to {MAX_RECOVERIES} missions the BLC refuses (split, then forbid / block and "
                   "plan again)" + (" and back out of a dead end." if c["recovery_back_out"] else
                                    "; neither backs out of a dead end."))
    else:
        out.append(f"Refusals gone round: CapPlanner {MAX_RECOVERIES}, A* {c['astar_max_recoveries']}.")
    out.append(f"Missions: A* walks its route in missions of at most {c['mission_length']:g} m and plans again "
               f"only after a refusal; CapPlanner merges its path's actions into missions of at most "
               f"{c['capplanner_mission_length']:g} m while their predicted success stays above "
               f"{c['capplanner_merge_min_success']:g}, and plans again at every mission start.")
    out.append("Topology: A* walks in the nominal topology; CapPlanner may change topology"
               + (" where the gain exceeds its ensemble's doubt about it." if c["capplanner_topology_doubt"] else "."))
    if c["capplanner_measured_stance"]:
        out.append("CapPlanner judges its next moves from the stance the robot stands in and backs out of a "
                   "stance its model foretells as a dead end; A* has no model of the BLC to do so.")
    if c["capplanner_refused_in_every_topology"]:
        out.append("A move the BLC refused is closed for CapPlanner in every topology from that cell and heading "
                   "(as A*, which has one, blocks it).")
    else:
        out.append("CapPlanner may try a move the BLC refused again in another topology.")
    if c["capplanner_min_route_success"] > 0:
        out.append(f"CapPlanner declines a task whose best path's predicted chance of no fall is below "
                   f"{c['capplanner_min_route_success']:g} (a failure here); A* declines only without a route.")
    return out


def report(out, against=None) -> dict:
    """The summary of a results folder as it stands (a run in progress included): rows,
    comparisons, failure reasons per planner, and how many tasks are done; with ``against``
    (another results folder of the same worlds) also each planner paired with its own walks
    there, and the settings that differ."""
    out = Path(out)
    if not (out / RESULTS).is_file():
        raise bad_value("results", str(out), f"no {RESULTS} there (run qz experiment capplanner-vs-astar)")
    records = read_results(out)
    reasons: dict[str, dict[str, int]] = {}
    errors: dict[str, int] = {}
    for r in records:
        if r["reason"] == "error":  # a crashed task: rerun on resume, not a failure of the planner
            errors[r["planner"]] = errors.get(r["planner"], 0) + 1
        elif not r["success"]:
            bucket = reasons.setdefault(r["planner"], {})
            bucket[r["reason"]] = bucket.get(r["reason"], 0) + 1
    summary = {"rows": summarise(records), "comparisons": compare_planners(records), "failure_reasons": reasons,
               "claim": claim_check(records), "errors": errors, "tasks_done": len(records),
               "wall_time_s": float(sum(r.get("wall_time_s", 0.0) for r in records)),
               "differences": planner_differences(_settings(out))}
    if (out / PREDICTIONS).is_file():  # written by qz experiment report --predict
        predictions = [json.loads(line) for line in (out / PREDICTIONS).read_text().splitlines() if line.strip()]
        summary["route_calibration"] = route_calibration(records, predictions)
    if against is not None:
        summary["against"] = _against(out, records, against)
    return summary


def report_markdown(summary: dict) -> str:
    """The report as Markdown tables: per cell both planners' success and displacement ratio,
    the paired comparison, and the failure reasons."""
    def rate(row):
        return "-" if row is None or row["success_rate"] is None else \
            f"{row['successes']}/{row['tasks']} ({100 * row['success_rate']:.0f} %)"

    def ratio(row):
        return "-" if row is None or row["displacement_ratio"] is None else f"{row['displacement_ratio']:.3f}"

    by_cell = {(r["terrain"], r["difficulty"], r["planner"]): r for r in summary["rows"]}
    lines = ["| terrain | difficulty | CapPlanner success | A* success | CapPlanner displacement ratio "
             "| A* displacement ratio |", "| --- | --- | --- | --- | --- | --- |"]
    for terrain in TERRAINS:
        for difficulty in DIFFICULTIES:
            cap, astar = by_cell.get((terrain, difficulty, "capplanner")), by_cell.get((terrain, difficulty, "astar"))
            if cap or astar:
                lines.append(f"| {terrain} | {difficulty} | {rate(cap)} | {rate(astar)} | {ratio(cap)} | {ratio(astar)} |")
    if summary["comparisons"]:
        lines += ["", "| terrain | difficulty | paired tasks | both | only CapPlanner | only A* | neither "
                      "| McNemar exact p |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for c in summary["comparisons"]:
            lines.append(f"| {c['terrain']} | {c['difficulty']} | {c['tasks']} | {c['both']} | {c['only_capplanner']} "
                         f"| {c['only_astar']} | {c['neither']} | {c['p_value']:.2g} |")
    claim = summary.get("claim")
    if claim:
        lo, hi = claim["difference_ci95"]
        rates = ", ".join(f"{d} {100 * r:.0f} % (aim {100 * CLAIM_RATES[d]:.0f} %: "
                          f"{'met' if claim['rates_hold'][d] else 'missed'})"
                          for d, r in claim["capplanner_rates"].items() if r is not None)
        power = "-" if claim["power"] is None else f"{100 * claim['power']:.0f} %"
        lines += ["", f"The aim on medium + hard ({claim['tasks']} paired tasks): CapPlanner "
                      f"{100 * claim['capplanner_rate']:.1f} %, A* {100 * claim['astar_rate']:.1f} %, difference "
                      f"{100 * claim['difference']:+.1f} points (95 % interval {100 * lo:+.1f} to {100 * hi:+.1f}), "
                      f"McNemar exact p = {claim['p_value']:.2g}: "
                      f"{'met' if claim['difference_holds'] else 'missed'} (at least "
                      f"{100 * CLAIM_DIFFERENCE:.0f} points with p < {CLAIM_ALPHA:g}). CapPlanner's success: {rates}. "
                      f"Design: {100 * claim['discordant_share']:.0f} % of the tasks discordant; power to find "
                      f"{100 * CLAIM_DIFFERENCE:.0f} points at p < {CLAIM_ALPHA:g}: {power}; "
                      + ("" if claim["tasks_per_cell_for_power"] is None else
                         f"{claim['tasks_per_cell_for_power']} tasks per cell would give "
                         f"{100 * CLAIM_POWER:.0f} %.")]
    if summary.get("route_calibration"):
        lines += ["", "| terrain | difficulty | CapPlanner set out | predicted no-fall | predicted success "
                      "| walked | declined (no path) | of those, A* walked |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]

        def num(v):
            return "-" if v is None else f"{v:.2f}"

        for c in summary["route_calibration"]:
            lines.append(f"| {c['terrain']} | {c['difficulty']} | {c['started']}/{c['tasks']} "
                         f"| {num(c['predicted_fall_free'])} | {num(c.get('predicted_success'))} "
                         f"| {num(c['walked_rate'])} | {c['declined']} | {c['declined_walked_by_astar']} |")
    if summary.get("against"):
        other = summary["against"]
        changed = ", ".join(f"{k} {v[0]} (there {v[1]})" for k, v in other["changed_settings"].items())
        lines += ["", f"Against {other['folder']} (settings that differ: {changed or 'none'}):", "",
                  "| planner | terrain | difficulty | paired tasks | this run | that run | both | only this "
                  "| only that | neither | McNemar exact p |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for c in other["comparisons"]:
            lines.append(f"| {c['planner']} | {c['terrain']} | {c['difficulty']} | {c['tasks']} "
                         f"| {c['this_successes']} | {c['other_successes']} | {c['both']} | {c['only_this']} "
                         f"| {c['only_other']} | {c['neither']} | {c['p_value']:.2g} |")
    if summary.get("discordant") is not None:
        names = PLANNER_NAMES
        lines += ["", f"Where each planner fails: {len(summary['discordant'])} discordant tasks", "",
                  "| task | walked | failed | reason | picture |", "| --- | --- | --- | --- | --- |"]
        for t in summary["discordant"]:
            lines.append(f"| {t['task']} | {names.get(t['walked'], t['walked'])} | "
                         f"{names.get(t['failed'], t['failed'])} | {t['reason']} | {t['picture']} |")
    if summary.get("differences"):
        lines += ["", "What differs between the planners' walks besides their plans:", ""]
        lines += [f"- {d}" for d in summary["differences"]]
    if summary["failure_reasons"]:
        lines += ["", "| planner | failures by reason |", "| --- | --- |"]
        for planner, reasons in sorted(summary["failure_reasons"].items()):
            text = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1]))
            lines.append(f"| {planner} | {text} |")
    return "\n".join(lines)


def _setting_owner(field: str) -> str | None:
    """The planner whose walks alone a setting changes (None: every planner's)."""
    if field.startswith("astar_"):
        return "astar"
    if field.startswith("capplanner_") or field in ("capability_model", MODEL_IDENTITY):
        return "capplanner"
    return None


def run_experiment(out, *, planners=tuple(PLANNERS), terrains=TERRAINS, difficulties=DIFFICULTIES,
                   tasks: int = TASKS_PER_CELL, workers: int = 1, ray_address: str | None = None,
                   config: ExperimentConfig = ExperimentConfig(), progress: bool = True,
                   first_seed: int = 0, recordings: int = 1, reuse=None) -> dict:
    """Runs (or resumes) the comparison into ``out``; returns the summary. ``progress``: walks
    done of the total on stderr (qz_drake.progress), or a ProgressReport to advance (a
    tuning's, over all its settings). Task seeds are
    ``first_seed`` to ``first_seed + tasks - 1`` (0-19: the experiment's; tuning uses
    worlds.TUNING_SEED_START on). The first ``recordings`` tasks of every terrain, difficulty
    and planner are recorded under ``out/recordings/<task>/``. ``reuse`` (a TaskSpec -> record
    or None) may hand over the record of a task instead of walking it: the record of a walk
    that this task's walk would repeat exactly (see ``_tune``).

    ``out/settings.json`` holds the settings the results were walked with. A resumed run must
    match it in every setting of the planners it walks that already have results there (and in
    those of every planner, such as the BLC's budget); a planner's own settings (``astar_*``;
    ``capplanner_*`` and the model) may differ while it has no results yet, so one planner's
    half can be walked before the other's is tuned."""
    from qz_drake.capability.collect import LocalPool, RayPool, check_ray_address, check_workers

    for p in planners:
        if p not in PLANNERS:
            raise bad_value("--planners", p, f"expected one of {', '.join(PLANNERS)}")
    if isinstance(tasks, bool) or tasks < 1:
        raise bad_value("--tasks", tasks, "must be a positive whole number")
    if tasks > MAX_TASKS_PER_CELL:
        raise bad_value("--tasks", tasks, f"more than {MAX_TASKS_PER_CELL} tasks per terrain and difficulty "
                                          f"(each a walk of minutes; the experiment's are {TASKS_PER_CELL})")
    check_workers(workers)
    if isinstance(config.blc_retries, bool) or not isinstance(config.blc_retries, int) or config.blc_retries < 0:
        raise bad_value("--blc-retries", config.blc_retries, "must be a whole number >= 0")
    if config.blc_retries > MAX_BLC_RETRIES:
        raise bad_value("--blc-retries", config.blc_retries, f"more than {MAX_BLC_RETRIES} (each retry is another "
                                                             f"BLC solve of a mission, one tripod cycle longer)")
    if not isinstance(config.blc_ladder, str):
        raise bad_value("--blc-ladder", config.blc_ladder, "expected rungs separated by commas")
    from qz_drake.systems.blc_plan import parse_ladder

    parse_ladder(config.blc_ladder, "--blc-ladder")
    if config.blc_ladder and config.blc_retries:
        raise bad_value("--blc-ladder", config.blc_ladder, "give a ladder or --blc-retries, not both")
    for t in terrains:
        make_task(t, "simple", 0, scale=config.scale)
    for d in difficulties:
        make_task("stairs", d, 0, scale=config.scale)
    model = None
    if "capplanner" in planners:
        from qz_drake.capability.model import CapabilityModel

        model = CapabilityModel.load(config.capability_model or None)  # a missing model fails before any walk
    if ray_address:
        check_ray_address(ray_address)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise bad_value("--out", str(out), "is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    settings = out / "settings.json"
    mine = dataclasses.asdict(config)
    if model is not None:
        mine[MODEL_IDENTITY] = model.identity
    stored = json.loads(settings.read_text()) if settings.is_file() else None
    if stored is not None:
        # A setting added since those results were written reads as its default there, unless
        # its coming changed the walks (SETTINGS_BEFORE_THEY_EXISTED).
        theirs = {**dataclasses.asdict(ExperimentConfig()), **SETTINGS_BEFORE_THEY_EXISTED, **stored}
        walked = {r.get("planner") for r in read_results(out) if r.get("reason") != "error"}
        for field in sorted(set(mine) | set(theirs)):
            owner = _setting_owner(field)
            if owner is not None and owner not in planners:
                # Not this run's planner: its settings stay those its walks (if any) had.
                if field in theirs:
                    mine[field] = theirs[field]
                else:
                    mine.pop(field, None)
            elif owner is not None and owner not in walked:
                continue  # this run's planner walks here first: its settings are this run's
            elif field == MODEL_IDENTITY and field not in stored:
                mine.pop(field, None)  # results written before the model was recorded carry none
            elif mine.get(field) != theirs.get(field):
                if field == MODEL_IDENTITY:
                    raise bad_value("--model", config.capability_model or "the shipped model",
                                    f"{out} holds CapPlanner results of another model ({theirs[field]}, "
                                    f"this one is {mine[field]}): use another --out")
                raise bad_value("--out", str(out), f"holds results of other experiment settings ({field} "
                                f"{theirs.get(field)}, this run's {mine.get(field)})")
    settings.write_text(json.dumps(mine, indent=1))
    done = {r["key"] for r in read_results(out) if r.get("reason") != "error"}
    if isinstance(recordings, bool) or recordings < 0:
        raise bad_value("--recordings", recordings, "must be a whole number, 0 or more")
    seeds = range(int(first_seed), int(first_seed) + tasks)

    def record_dir(t, d, s, p):
        if s >= int(first_seed) + recordings:
            return ""
        return str(out / "recordings" / TaskSpec(t, d, s, p).key)

    # Seed by seed across every cell and planner: a run stopped part way (a session's end)
    # holds whole pairs spread evenly over the cells, not the first cells complete.
    specs = [TaskSpec(t, d, s, p, record_dir(t, d, s, p))
             for s in seeds for t in terrains for d in difficulties for p in planners]
    todo = [s for s in specs if s.key not in done]
    reused = 0
    clock = time.perf_counter()
    if isinstance(progress, ProgressReport):  # a tuning's, over all its settings
        report, owned = progress, contextlib.nullcontext(progress)
        report.update(advance=len(specs) - len(todo))
    else:
        report = owned = ProgressReport("capplanner-vs-astar", len(specs), unit="walks",
                                        completed=len(specs) - len(todo), enabled=progress)

    with owned, (out / RESULTS).open("a") as sink:
        def on_record(record):
            sink.write(json.dumps(record) + "\n")
            sink.flush()
            outcome = "succeeded" if record.get("success") else record.get("reason") or "failed"
            report.update(advance=1, status=f"last: {record['key']} {outcome}")

        if reuse is not None:
            walk = []
            for spec in todo:
                record = reuse(spec)
                if record is None:
                    walk.append(spec)
                else:
                    on_record(record)
                    reused += 1
            todo = walk
        if todo:
            pool = RayPool(ray_address, config, 1, function=run_task, crashed=_crashed) if ray_address else \
                LocalPool(min(workers, len(todo)), config, 1, function=run_task, crashed=_crashed,
                          max_tasks=WALKS_PER_WORKER)
            try:
                pool.run(todo, on_record)
            finally:
                pool.close()
    # The summary holds every planner's results on this run's tasks (the other half too).
    keys = {TaskSpec(s.terrain, s.difficulty, s.seed, p).key for s in specs for p in PLANNERS}
    records = [r for r in read_results(out) if r["key"] in keys]
    rows = summarise(records)
    comparisons = compare_planners(records)
    (out / "results.json").write_text(json.dumps({"rows": rows, "comparisons": comparisons, "records": records},
                                                 indent=1))
    _write_csv(out / "results.csv", records)
    return {"rows": rows, "comparisons": comparisons, "ran": len(todo), "reused": reused,
            "already_done": len(specs) - len(todo) - reused,
            "wall_time_s": time.perf_counter() - clock, "out": str(out)}


def _write_csv(path: Path, records: list[dict]) -> None:
    import csv

    fields = ["key", "terrain", "difficulty", "seed", "planner", "success", "reason", "straight_m", "walked_m",
              "displacement_ratio", "missions", "replans", "recoveries", "back_outs", "topology_changes",
              "planning_time_s", "wall_time_s"]
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        for r in records:
            writer.writerow(r)


# The grid ``tune_astar`` searches by default: blocking thresholds around paper 003's (a step
# the robot's legs can take, Qingzhui's 0.26 m stair rise at most; slopes its feet hold).
TUNING_STEP_HEIGHTS = (0.12, 0.16, 0.20, 0.24)
TUNING_SLOPES_DEG = (20.0, 30.0)
# The trunk alone, and the trunk with the legs' reach (astar_baseline.AStarBaselineConfig). [m]
TUNING_BODY_RADII = (0.7, 0.9)


# Each tuning's report keys -> the ExperimentConfig fields they set.
ASTAR_TUNED = {"max_step_height": "astar_max_step_height", "max_slope_deg": "astar_max_slope_deg",
               "body_radius": "astar_body_radius"}
CAPPLANNER_TUNED = {"failure_reward": "capplanner_failure_reward",
                    "topology_change_cost": "capplanner_topology_change_cost",
                    "plan_failure_risk": "capplanner_plan_failure_risk",
                    "mission_length": "capplanner_mission_length",
                    "merge_min_success": "capplanner_merge_min_success",
                    "topology_doubt": "capplanner_topology_doubt"}
# Tuning tasks per terrain and difficulty for either planner (issue 38: with two, every A*
# setting scored 9-11 of 18 and the choice was noise).
TUNING_TASKS_PER_CELL = 4
# The difficulties both planners are tuned on: the aim is about medium and hard (CLAIM_RATES);
# on simple worlds either planner walked every tuning task whatever its setting (the previous
# tunings, 2 tasks a cell: each of A*'s 16 settings and CapPlanner's 2 walked 6 of 6 simple
# tasks), so those walks chose nothing and cost a third of a tuning.
TUNING_DIFFICULTIES: tuple[str, ...] = ("medium", "hard")


def _tuned_settings(path, names: dict, flag: str, command: str) -> dict:
    """The ExperimentConfig fields of a tuning's chosen setting (``tuning.json``, or its folder)."""
    path = Path(path)
    file = path / "tuning.json" if path.is_dir() else path
    # A tuning from before a setting existed was walked with SETTINGS_BEFORE_THEY_EXISTED's value.
    defaults = dataclasses.replace(ExperimentConfig(), **{k: v for k, v in SETTINGS_BEFORE_THEY_EXISTED.items()
                                                         if k in names.values()})
    try:
        chosen = json.loads(file.read_text())["chosen"]
        if not isinstance(chosen, dict) or not set(chosen) & set(names):
            raise KeyError("chosen")
        return {field: type(getattr(defaults, field))(chosen.get(key, getattr(defaults, field)))
                for key, field in names.items()}
    except FileNotFoundError:
        raise bad_value(flag, str(path), f"no tuning.json there (run qz experiment {command})") from None
    except (ValueError, KeyError, TypeError):
        raise bad_value(flag, str(file), f"not a tuning.json of qz experiment {command}") from None


def astar_settings(path) -> dict:
    """The ExperimentConfig fields of a tuning's chosen A* setting (``tuning.json`` of
    ``tune_astar``, or its folder): astar_max_step_height, astar_max_slope_deg,
    astar_body_radius."""
    return _tuned_settings(path, ASTAR_TUNED, "--astar-tuning", "tune-astar")


def capplanner_settings(path) -> dict:
    """The ExperimentConfig fields of ``tune_capplanner``'s chosen setting: capplanner_failure_reward,
    capplanner_topology_change_cost, capplanner_plan_failure_risk, capplanner_mission_length and
    capplanner_merge_min_success (a tuning without one of them: its default)."""
    return _tuned_settings(path, CAPPLANNER_TUNED, "--capplanner-tuning", "tune-capplanner")


def _astar_walk(spec: TaskSpec, config: ExperimentConfig) -> tuple[str | None, float]:
    """What A*'s walk of a task depends on, hashed, and the route's planning time: the world
    and the waypoints (the walk follows them and nothing else of the A* settings), and every
    setting of the run but A*'s. None when A* finds no route (nothing is walked then)."""
    import hashlib

    task = make_task(spec.terrain, spec.difficulty, spec.seed, scale=config.scale)
    route, _, waypoints, _ = _astar(task, config)
    if not route.found:
        return None, route.planning_time_s
    # With the recovery a refused mission is gone round on A*'s own cost map: the walk then
    # depends on every A* setting too.
    others = {k: v for k, v in dataclasses.asdict(config).items()
              if config.astar_max_recoveries > 0 or not k.startswith("astar_")}
    payload = json.dumps([spec.terrain, spec.difficulty, spec.seed, spec.planner, others, waypoints])
    return hashlib.sha256(payload.encode()).hexdigest(), route.planning_time_s


# Planners whose walk is fixed before it starts (name -> TaskSpec, config -> (walk hash or None,
# planning time)): a tuning walks each distinct walk once. CapPlanner plans as it walks (its MDP
# settings act on every replan), so each of its settings walks its tasks.
FIXED_WALKS = {"astar": _astar_walk}


def _tune(out, planner: str, grid: list[dict], names: dict, folder_of, *, terrains, difficulties, tasks: int,
          workers: int, ray_address, config: ExperimentConfig, progress: bool) -> dict:
    """Walks ``tasks`` tuning tasks per terrain and difficulty (seeds from
    worlds.TUNING_SEED_START, never the experiment's 0-19) with each setting of ``grid`` (report
    keys, see ``names``), each in its own resumable folder under ``out``; keeps the setting with
    the most successes (ties: the smaller mean displacement ratio, then the first in the grid).
    Writes ``tuning.json``.

    Where a planner's walk is fixed by its route (``FIXED_WALKS``), a task whose route under
    this setting is one an earlier setting already walked is not walked again (the simulation
    is deterministic): its record is that walk's, with ``walk_of`` naming the folder that walked
    it and this setting's own planning time."""
    from qz_drake.experiments.worlds import TUNING_SEED_START

    out = Path(out)
    results = []
    fixed = FIXED_WALKS.get(planner)
    walks: dict[str, tuple[dict, str]] = {}  # walk hash -> (the record of that walk, its folder)
    per_setting = len(terrains) * len(difficulties) * tasks
    with ProgressReport(f"tune-{planner}", len(grid) * per_setting, unit="walks", enabled=progress) as bar:
        for number, setting in enumerate(grid, 1):
            bar.update(description=f"tune-{planner}: setting {number}/{len(grid)}")
            results.append(_tune_setting(out, planner, setting, names, folder_of, fixed, walks, terrains=terrains,
                                         difficulties=difficulties, tasks=tasks, workers=workers,
                                         ray_address=ray_address, config=config, bar=bar))
    ranked = sorted(enumerate(results), key=lambda item: (item[1]["successes"],
                                                          -(item[1]["displacement_ratio"] or np.inf),
                                                          -item[0]), reverse=True)
    best = ranked[0][1]
    report = {"planner": planner, "chosen": {k: best[k] for k in grid[0]},
              "grid": results, "tasks_per_cell": tasks, "first_seed": TUNING_SEED_START,
              "margin": _margin(best, ranked[1][1] if len(ranked) > 1 else None, list(grid[0]))}
    out.mkdir(parents=True, exist_ok=True)
    (out / "tuning.json").write_text(json.dumps(report, indent=1))
    return report


def _margin(best: dict, runner_up: dict | None, names: list) -> dict | None:
    """How far the chosen setting is ahead of the runner-up, on the same tuning tasks: the
    successes of each, the tasks only one of them walked and McNemar's exact p of that (a
    margin inside the noise says the choice is one of equals)."""
    if runner_up is None:
        return None
    from qz_drake.capability.evaluation import mcnemar_exact_p

    walked = [{r["key"]: bool(r["success"]) for r in read_results(Path(row["folder"])) if r.get("reason") != "error"}
              for row in (best, runner_up)]
    shared = sorted(set(walked[0]) & set(walked[1]))
    only_best = sum(walked[0][k] and not walked[1][k] for k in shared)
    only_runner_up = sum(walked[1][k] and not walked[0][k] for k in shared)
    return {"runner_up": {k: runner_up[k] for k in names}, "successes": best["successes"],
            "runner_up_successes": runner_up["successes"], "tasks_both": len(shared),
            "only_chosen": only_best, "only_runner_up": only_runner_up,
            "mcnemar_p": mcnemar_exact_p(only_best, only_runner_up)}


def _tune_setting(out: Path, planner: str, setting: dict, names: dict, folder_of, fixed, walks: dict, *,
                  terrains, difficulties, tasks: int, workers: int, ray_address, config: ExperimentConfig,
                  bar) -> dict:
    """One setting of ``_tune``'s grid: its walks (those another setting already walked taken
    from ``walks``, which gains this setting's), and its row of the tuning report."""
    from qz_drake.experiments.worlds import TUNING_SEED_START

    trial = dataclasses.replace(config, **{names[k]: type(getattr(config, names[k]))(v) for k, v in setting.items()})
    folder = out / folder_of(setting)
    hashes: dict[str, str | None] = {}

    def reuse(spec, trial=trial, hashes=hashes):
        hashes[spec.key], planning_time = fixed(spec, trial)
        if hashes[spec.key] not in walks:
            return None
        walked, walker = walks[hashes[spec.key]]
        # Its time is this setting's route; the walk's is in the folder that walked it.
        return {**walked, "planning_time_s": planning_time, "wall_time_s": planning_time,
                "walk_of": walked.get("walk_of", walker)}

    summary = run_experiment(folder, planners=(planner,), terrains=terrains, difficulties=difficulties,
                             tasks=tasks, workers=workers, ray_address=ray_address, config=trial,
                             progress=bar, first_seed=TUNING_SEED_START, recordings=0,
                             reuse=reuse if fixed else None)
    keys = {TaskSpec(t, d, TUNING_SEED_START + i, planner).key
            for t in terrains for d in difficulties for i in range(tasks)}
    records = [r for r in read_results(folder) if r["key"] in keys and r.get("reason") != "error"]
    if fixed:
        for r in records:
            if r["key"] not in hashes:  # walked before this call (a resumed tuning)
                spec = TaskSpec(r["terrain"], r["difficulty"], r["seed"], r["planner"])
                hashes[r["key"]] = fixed(spec, trial)[0]
            if hashes[r["key"]] and hashes[r["key"]] not in walks:
                walks[hashes[r["key"]]] = (r, folder.name)
    rows = summary["rows"]
    done = sum(r["tasks"] for r in rows)
    ok = sum(r["successes"] for r in rows)
    ratios = [r["displacement_ratio"] for r in rows if r["displacement_ratio"] is not None]
    return {**{k: v if isinstance(v, bool) else float(v) for k, v in setting.items()}, "tasks": done, "successes": ok,
            "success_rate": ok / done if done else None,
            "displacement_ratio": float(np.mean(ratios)) if ratios else None,
            "walked": sum(1 for r in records if "walk_of" not in r and r["reason"] != "planner"),
            "rows": rows, "folder": str(folder)}


def _check_numbers(flag: str, numbers, ok, expected: str) -> None:
    if not numbers or any(not (isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and ok(v))
                          for v in numbers):
        raise bad_value(flag, list(numbers), expected)


def tune_astar(out, *, step_heights=TUNING_STEP_HEIGHTS, slopes_deg=TUNING_SLOPES_DEG,
               body_radii=TUNING_BODY_RADII,
               terrains=TERRAINS, difficulties=TUNING_DIFFICULTIES, tasks: int = TUNING_TASKS_PER_CELL,
               workers: int = 1, ray_address: str | None = None, config: ExperimentConfig = ExperimentConfig(),
               progress: bool = True) -> dict:
    """Tunes the A* baseline's thresholds as strongly as it honestly can be: every
    (max step height, max slope, body radius) of the grid on the tuning worlds (``_tune``)."""
    for flag, numbers in (("--steps", step_heights), ("--slopes", slopes_deg), ("--radii", body_radii)):
        _check_numbers(flag, numbers, lambda v: v > 0, "expected positive numbers")
    grid = [{"max_step_height": float(step), "max_slope_deg": float(slope), "body_radius": float(radius)}
            for radius in body_radii for step in step_heights for slope in slopes_deg]
    return _tune(out, "astar", grid, ASTAR_TUNED,
                 lambda g: f"step{g['max_step_height']:.2f}_slope{g['max_slope_deg']:g}_radius{g['body_radius']:.2f}",
                 terrains=terrains, difficulties=difficulties, tasks=tasks, workers=workers,
                 ray_address=ray_address, config=config, progress=progress)


# The grid ``tune_capplanner`` searches by default (16 settings, as many as A*'s): the fall's
# penalty against the goal's 100 (how much risk a shorter route may carry); the share of the
# predicted refusals counted as falls (session 38: CapPlanner's failed validation walks ended in
# stances the BLC refused every way out of, where the MDP had priced a refusal as a stand and a
# retry); the split of the path into missions (the longest mission [m], a diagonal cell's 1.42 m
# at least, and the merge threshold). A topology change is doubted by the ensemble's
# disagreement about the difference (capability_mdp.CapabilityMdpConfig.topology_doubt, on by
# default since session 38), which leaves its price little to decide: one value.
TUNING_FAILURE_REWARDS = (-100.0, -200.0)
TUNING_TOPOLOGY_CHANGE_COSTS = (2.0,)
TUNING_PLAN_FAILURE_RISKS = (0.0, 1.0)
TUNING_MISSION_LENGTHS = (1.5, 2.0)
TUNING_MERGE_MIN_SUCCESS = (0.8, 0.95)
TUNING_TOPOLOGY_DOUBTS = (True,)


def tune_capplanner(out, *, failure_rewards=TUNING_FAILURE_REWARDS,
                    topology_change_costs=TUNING_TOPOLOGY_CHANGE_COSTS,
                    plan_failure_risks=TUNING_PLAN_FAILURE_RISKS, mission_lengths=TUNING_MISSION_LENGTHS,
                    merge_min_success=TUNING_MERGE_MIN_SUCCESS, topology_doubts=TUNING_TOPOLOGY_DOUBTS,
                    terrains=TERRAINS,
                    difficulties=TUNING_DIFFICULTIES, tasks: int = TUNING_TASKS_PER_CELL, workers: int = 1,
                    ray_address: str | None = None, config: ExperimentConfig = ExperimentConfig(),
                    progress: bool = True) -> dict:
    """Tunes CapPlanner's failure reward, topology-change cost, longest mission and merge
    threshold the way A* is tuned: every combination of the grid on the same tuning worlds
    (``_tune``)."""
    from qz_drake.planning.guidance import MissionSplitConfig

    _check_numbers("--failure-rewards", failure_rewards, lambda v: v < 0, "expected negative numbers")
    _check_numbers("--switch-costs", topology_change_costs, lambda v: v >= 0, "expected numbers >= 0")
    _check_numbers("--plan-failure-risks", plan_failure_risks, lambda v: 0 <= v <= 1, "expected numbers in [0, 1]")
    _check_numbers("--mission-lengths", mission_lengths, lambda v: v >= 1.42, "expected lengths >= 1.42 m "
                                                                                "(a diagonal move)")
    _check_numbers("--merge-thresholds", merge_min_success, lambda v: 0 <= v <= 1, "expected numbers in [0, 1]")
    if not topology_doubts or not all(isinstance(d, (bool, np.bool_)) for d in topology_doubts):
        raise bad_value("--topology-doubts", list(topology_doubts), "expected true/false values")
    grid = [{"failure_reward": float(f), "topology_change_cost": float(c), "plan_failure_risk": float(r),
             "mission_length": float(m), "merge_min_success": float(s), "topology_doubt": bool(d)}
            for d in topology_doubts for r in plan_failure_risks for f in failure_rewards
            for c in topology_change_costs for m in mission_lengths for s in merge_min_success]
    split = MissionSplitConfig()
    # Folders of the settings at the defaults keep the names they had before these were settings.
    return _tune(out, "capplanner", grid, CAPPLANNER_TUNED,
                 lambda g: f"failure{-g['failure_reward']:g}_switch{g['topology_change_cost']:g}"
                           + (f"_risk{g['plan_failure_risk']:g}" if g["plan_failure_risk"] else "")
                           + (f"_missions{g['mission_length']:g}" if g["mission_length"] != split.max_length else "")
                           + (f"_merge{g['merge_min_success']:g}" if g["merge_min_success"] != split.min_success
                              else "")
                           + ("" if g["topology_doubt"] else "_nodoubt"),
                 terrains=terrains, difficulties=difficulties, tasks=tasks, workers=workers,
                 ray_address=ray_address, config=config, progress=progress)
