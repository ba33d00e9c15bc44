"""Runs (or resumes) the Fig. 9 experiment into a results folder.

Every task of the chosen terrains, difficulties and planners is walked (tasks.run_task) by
local workers or on Ray. Results are appended to ``results.jsonl`` as tasks finish (one
writer: the driver), so a run resumes where it stopped and never runs a task twice;
``settings.json`` holds the settings they were walked with, which a resumed run must match.
At the end the summary goes to ``results.json`` and the records to ``results.csv``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
import time
from pathlib import Path

from qz_drake.errors import bad_value
from qz_drake.progress import ProgressReport
from qz_drake.experiments.fig9.comparison import compare_planners, summarise
from qz_drake.experiments.fig9.results import (MODEL_IDENTITY, RESULTS, SETTINGS_BEFORE_THEY_EXISTED,
                                               drop_cut_off_record, read_results)
from qz_drake.experiments.fig9.tasks import (EXPERIMENT_PLANNERS, MODEL_PLANNERS, PLANNERS, ExperimentConfig, TaskSpec,
                                             check_drives, run_task)
from qz_drake.experiments.worlds import DIFFICULTIES, TASKS_PER_CELL, TERRAINS, make_task

# Most tasks per terrain and difficulty one run may plan: 20 times the experiment's.
MAX_TASKS_PER_CELL = 20 * TASKS_PER_CELL
# Most BLC retries of a mission: each one is another solve of up to blc_time_limit seconds.
MAX_BLC_RETRIES = 10


# Walks a worker process (local or Ray's) makes before a fresh one takes its place: every walk's
# diagram stays in the process that built it (LocalPool), 100-200 MB a full-size walk. With 20 the
# decisive run's workers held at most 3.0 GB, but with the ladder and the route check the fresh
# run's first two reached 3.9 GB by their 20th walk (session 56; issue 55 allows a worker 4 GB):
# at their rate (1.1 GB, then about 140 MB a walk) 15 walks leave a Ray worker near 3.2 GB, and a
# fresh worker's start (a few seconds) stays small beside them.
WALKS_PER_WORKER = 15
# A local worker that holds this much after a walk is replaced too, whatever its count (Ray's
# workers are replaced by the count alone). [MB]
WORKER_MEMORY_MB = 3000.0


def _crashed(spec: TaskSpec, message: str, config) -> dict:
    return {"key": spec.key, "terrain": spec.terrain, "difficulty": spec.difficulty, "seed": spec.seed,
            "planner": spec.planner, "success": False, "reason": "error", "error": message}


def _setting_owners(field: str) -> tuple[str, ...] | None:
    """The planners whose walks alone a setting changes (None: every planner's)."""
    if field.startswith("astar_learned_"):
        return ("astar_learned",)
    if field.startswith("astar_"):
        return ("astar", "astar_learned")
    if field.startswith("capplanner_"):
        return ("capplanner",)
    if field in ("capability_model", MODEL_IDENTITY):
        return MODEL_PLANNERS
    return None


def run_experiment(out, *, planners=EXPERIMENT_PLANNERS, terrains=TERRAINS, difficulties=DIFFICULTIES,
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
    that this task's walk would repeat exactly (see ``tune._tune``).

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
    from qz_drake.experiments.worlds import seed_role

    if isinstance(first_seed, bool) or not isinstance(first_seed, int) or first_seed < 0:
        raise bad_value("--first-seed", first_seed, "must be a whole number >= 0")
    reserved = [s for s in range(first_seed, first_seed + tasks) if seed_role(s) == "reserved"]
    if reserved:
        raise bad_value("--first-seed", first_seed, f"its {tasks} tasks reach seed {reserved[0]}: seeds 50-99 are "
                                                    "kept for checks outside the project (never walked here)")
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
    from qz_drake.planning.route_check import check_route_check

    check_route_check(config.route_check, "--route-check")
    check_drives(config.control_mode, config.time_step)
    from qz_drake.trajopt.parameters import BlcParameters

    BlcParameters(leg_clearance_softmin=config.blc_leg_clearance_softmin)  # its error names the field
    from qz_drake.planning.capplanner_route import check_topologies

    check_topologies(config.capplanner_topologies, "--capplanner-topologies")
    for t in terrains:
        make_task(t, "simple", 0, scale=config.scale)
    for d in difficulties:
        make_task("stairs", d, 0, scale=config.scale)
    model = None
    if set(MODEL_PLANNERS) & set(planners):
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
            owners = _setting_owners(field)
            if owners is not None and not set(owners) & set(planners):
                # Not this run's planner: its settings stay those its walks (if any) had.
                if field in theirs:
                    mine[field] = theirs[field]
                else:
                    mine.pop(field, None)
            elif owners is not None and not set(owners) & walked:
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

    if drop_cut_off_record(out / RESULTS):
        print(f"{out / RESULTS}: dropped the last record, cut off in writing; its task is walked again",
              file=sys.stderr)
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
            pool = RayPool(ray_address, config, 1, function=run_task, crashed=_crashed, max_calls=WALKS_PER_WORKER,
                           workers=workers) if ray_address else \
                LocalPool(min(workers, len(todo)), config, 1, function=run_task, crashed=_crashed,
                          max_tasks=WALKS_PER_WORKER, max_memory_mb=WORKER_MEMORY_MB)
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
