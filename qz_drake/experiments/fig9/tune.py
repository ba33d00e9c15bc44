"""Each planner's settings chosen on tuning worlds (seeds from worlds.TUNING_SEED_START, never
the experiment's): ``tune_astar`` searches A*'s blocking thresholds and body radius,
``tune_capplanner`` CapPlanner's risk and mission split, each setting of the grid walked by
run.run_experiment in a resumable folder of its own; ``astar_settings`` and
``capplanner_settings`` read the chosen setting back for a run.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.progress import ProgressReport
from qz_drake.experiments.fig9.results import SETTINGS_BEFORE_THEY_EXISTED, read_results
from qz_drake.experiments.fig9.run import run_experiment
from qz_drake.experiments.fig9.tasks import ExperimentConfig, TaskSpec, _astar
from qz_drake.experiments.worlds import TERRAINS, make_task

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
                    "topology_doubt": "capplanner_topology_doubt",
                    "pessimism": "capplanner_pessimism", "edge_cost": "capplanner_edge_cost"}
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
# How far an action's success is doubted by the ensemble's spread (CapabilityMdpConfig.pessimism):
# one value unless searched (--pessimisms).
TUNING_PESSIMISMS = (1.0,)
# What a move near an edge costs (CapabilityMdpConfig.edge_cost): none unless searched (--edge-costs).
TUNING_EDGE_COSTS = (0.0,)


def tune_capplanner(out, *, failure_rewards=TUNING_FAILURE_REWARDS,
                    topology_change_costs=TUNING_TOPOLOGY_CHANGE_COSTS,
                    plan_failure_risks=TUNING_PLAN_FAILURE_RISKS, mission_lengths=TUNING_MISSION_LENGTHS,
                    merge_min_success=TUNING_MERGE_MIN_SUCCESS, topology_doubts=TUNING_TOPOLOGY_DOUBTS,
                    pessimisms=TUNING_PESSIMISMS, edge_costs=TUNING_EDGE_COSTS, terrains=TERRAINS,
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
    _check_numbers("--pessimisms", pessimisms, lambda v: v >= 0, "expected numbers >= 0")
    _check_numbers("--edge-costs", edge_costs, lambda v: v >= 0, "expected numbers >= 0")
    if not topology_doubts or not all(isinstance(d, (bool, np.bool_)) for d in topology_doubts):
        raise bad_value("--topology-doubts", list(topology_doubts), "expected true/false values")
    grid = [{"failure_reward": float(f), "topology_change_cost": float(c), "plan_failure_risk": float(r),
             "mission_length": float(m), "merge_min_success": float(s), "topology_doubt": bool(d),
             "pessimism": float(e), "edge_cost": float(g)}
            for d in topology_doubts for r in plan_failure_risks for f in failure_rewards
            for c in topology_change_costs for m in mission_lengths for s in merge_min_success for e in pessimisms
            for g in edge_costs]
    split = MissionSplitConfig()
    # Folders of the settings at the defaults keep the names they had before these were settings.
    return _tune(out, "capplanner", grid, CAPPLANNER_TUNED,
                 lambda g: f"failure{-g['failure_reward']:g}_switch{g['topology_change_cost']:g}"
                           + (f"_risk{g['plan_failure_risk']:g}" if g["plan_failure_risk"] else "")
                           + (f"_missions{g['mission_length']:g}" if g["mission_length"] != split.max_length else "")
                           + (f"_merge{g['merge_min_success']:g}" if g["merge_min_success"] != split.min_success
                              else "")
                           + ("" if g["topology_doubt"] else "_nodoubt")
                           + ("" if g["pessimism"] == 1.0 else f"_pessimism{g['pessimism']:g}")
                           + ("" if g["edge_cost"] == 0.0 else f"_edge{g['edge_cost']:g}"),
                 terrains=terrains, difficulties=difficulties, tasks=tasks, workers=workers,
                 ray_address=ray_address, config=config, progress=progress)
