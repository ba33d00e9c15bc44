"""The report of a Fig. 9 results folder (``qz experiment report``), a run in progress too: both
planners' success per cell, the paired comparison and the aim, the route calibration where
predictions exist, the failure reasons, what differs between the planners' walks besides their
plans, each planner against another run, and pictures of the discordant tasks; as a dict or as
Markdown tables.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from qz_drake.errors import bad_value
from qz_drake.experiments.fig9.comparison import (CLAIM_ALPHA, CLAIM_DIFFERENCE, CLAIM_POWER,
                                                  claim_aims, claim_check, compare_planners, compare_runs, summarise)
from qz_drake.experiments.fig9.predict import ROUTE_PREDICTIONS, route_calibration, route_calibration_check
from qz_drake.experiments.fig9.results import (PREDICTIONS, RESULTS, SETTINGS_BEFORE_THEY_EXISTED, read_json_lines,
                                               read_results, read_settings)
from qz_drake.experiments.fig9.tasks import ExperimentConfig
from qz_drake.experiments.worlds import DIFFICULTIES, PLANNER_NAMES, TERRAINS, make_task


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
    if c.get("blc_terminal_stance", "free") == "canonical":
        retry += ", every mission ending in its target's canonical stance"
    if c.get("blc_leg_clearance_softmin") is not None:
        retry += (", each leg's clearance a smooth minimum over its links (sharpness "
                  f"{c['blc_leg_clearance_softmin']:g} / m)")
    step_ms = 1000.0 * float(c.get("time_step", 0.002))
    drives = (f"joint PD (Eq. 7 in the controller, {step_ms:g} ms plant steps)" if c.get("control_mode", "torque") ==
              "torque" else f"joint PD (Eq. 7's PD in the drives, {step_ms:g} ms plant steps)")
    out = [f"Shared: the BLC ({c['blc_max_iterations']} Ipopt iterations a mission, {retry}), the IK tracker "
           f"and {drives}, the strict verdict, the time budget ({c['time_factor']:g} x the straight-line walking "
           f"time + {c['time_margin']:g} s), the speed and tripod phase."]
    if c["astar_max_recoveries"] == MAX_RECOVERIES:
        out.append(f"Both go round up to {MAX_RECOVERIES} missions the BLC refuses (split, then forbid / block and "
                   "plan again)" + (" and back out of a dead end." if c["recovery_back_out"] else
                                    "; neither backs out of a dead end."))
    else:
        out.append(f"Refusals gone round: CapPlanner {MAX_RECOVERIES}, A* {c['astar_max_recoveries']}.")
    if c.get("route_check"):
        out.append(f"Both plan the next {c['route_check']} mission{'s' if c['route_check'] > 1 else ''} of every "
                   "route with the walk's BLC before handing it out, and go round a refusal foreseen there as round "
                   "one met.")
    out.append(f"Missions: A* walks its route in missions of at most {c['mission_length']:g} m and plans again "
               f"only after a refusal; CapPlanner merges its path's actions into missions of at most "
               f"{c['capplanner_mission_length']:g} m while their predicted success stays above "
               f"{c['capplanner_merge_min_success']:g}"
               + (" (a turn in place always with the move after it)" if c.get("capplanner_turns_with_moves") else "")
               + ", and plans again at every mission start"
               + (f", keeping its route unless the new one is worth more than {c['capplanner_hold_margin']:g}."
                  if c.get("capplanner_hold_margin") is not None else "."))
    if c.get("capplanner_topologies") == "nominal":
        out.append("Topology: both walk in the nominal topology.")
    else:
        out.append("Topology: A* walks in the nominal topology; CapPlanner may change topology"
                   + (f" (to {c['capplanner_topologies'].replace(',', ', ')})" if c.get("capplanner_topologies") else "")
                   + (" where the gain exceeds its ensemble's doubt about it." if c["capplanner_topology_doubt"]
                      else "."))
    if c.get("capplanner_edge_cost"):
        out.append(f"CapPlanner charges a move or turn up to {c['capplanner_edge_cost']:g} for passing within 0.5 m "
                   f"of an edge; A*'s cost map keeps its body disc ({c['astar_body_radius']:g} m) off obstacles.")
    if c.get("capplanner_turn_edge_risk"):
        out.append(f"CapPlanner counts a turn within 0.4 m of an edge as failing up to "
                   f"{c['capplanner_turn_edge_risk']:g} of the time (its walks' turns beside boxes), whatever its "
                   "model says.")
    if c.get("capplanner_revisit_cost"):
        out.append(f"A move into a cell costs CapPlanner {c['capplanner_revisit_cost']:g} more for each mission that "
                   "ended there (it goes on somewhere new rather than back and forth); A* plans again only after a "
                   "refusal.")
    if c.get("capplanner_target_shift"):
        out.append(f"CapPlanner's mission targets move up to {c['capplanner_target_shift']:g} m from their cell's "
                   "centre, away from edges; A*'s waypoints keep its body disc off obstacles.")
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


def route_rows(records: list[dict]) -> list[dict]:
    """Per planner and difficulty, how the walks' routes held (issue 54's aims: the displacement
    ratio, back-outs per walk, and the replans that changed the next 2 m of route without a
    refusal or a lost route): walks (errors left out), mean displacement ratio of the
    successful ones, back-outs and refusals gone round per walk, replans and topology changes
    per walk, and, for walks that logged their replans' decisions (CapPlanner since session
    47), the changed replans and their share of those walks' replans (None without any)."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in records:
        if r.get("reason") != "error":
            groups.setdefault((r["planner"], r["difficulty"]), []).append(r)
    rows = []
    for (planner, difficulty), walks in sorted(groups.items(), key=lambda kv: (
            kv[0][0], DIFFICULTIES.index(kv[0][1]) if kv[0][1] in DIFFICULTIES else 99)):
        ratios = [r["displacement_ratio"] for r in walks if r.get("displacement_ratio") is not None]
        logged = [r for r in walks if r.get("route_decisions")]
        replans = sum(int(r.get("replans", 0)) for r in logged)
        changed = sum(int(r["route_decisions"].get("changed", 0)) for r in logged)
        rows.append({"planner": planner, "difficulty": difficulty, "walks": len(walks),
                     "displacement_ratio": float(np.mean(ratios)) if ratios else None,
                     "back_outs_per_walk": float(np.mean([int(r.get("back_outs", 0)) for r in walks])),
                     "recoveries_per_walk": float(np.mean([int(r.get("recoveries", 0)) for r in walks])),
                     "replans_per_walk": float(np.mean([int(r.get("replans", 0)) for r in walks])),
                     "topology_changes_per_walk": float(np.mean([int(r.get("topology_changes", 0)) for r in walks])),
                     "logged_walks": len(logged), "changed_replans": changed,
                     "changed_share": changed / replans if replans else None})
    return rows


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
    summary = {"rows": summarise(records), "comparisons": compare_planners(records),
               "comparisons_learned": compare_planners(records, baseline="astar_learned"), "failure_reasons": reasons,
               "claim": claim_check(records), "errors": errors, "tasks_done": len(records),
               "wall_time_s": float(sum(r.get("wall_time_s", 0.0) for r in records)),
               "differences": planner_differences(read_settings(out)), "routes": route_rows(records)}
    if (out / PREDICTIONS).is_file():  # written by qz experiment report --predict
        predictions = read_json_lines(out / PREDICTIONS)
        summary["route_calibration"] = route_calibration(records, predictions)
        aims = claim_aims(records)
        if aims["route_tolerance"] is not None:
            summary["route_calibration_check"] = dict(
                route_calibration_check(summary["route_calibration"], aims["route_tolerance"]), issue=aims["issue"])
    if against is not None:
        summary["against"] = _against(out, records, against)
    return summary


def _against(out: Path, records: list[dict], against) -> dict:
    """The comparison of a results folder with another one (``report(..., against=)``)."""
    against = Path(against)
    if not (against / RESULTS).is_file():
        raise bad_value("against", str(against), f"no {RESULTS} there (run qz experiment capplanner-vs-astar)")
    mine, theirs = read_settings(out), read_settings(against)
    scales = (float(mine.get("scale", 1.0)), float(theirs.get("scale", 1.0)))
    if scales[0] != scales[1]:
        raise bad_value("against", str(against), f"its worlds are at scale {scales[1]:g} and this run's at "
                        f"{scales[0]:g}: not the same tasks")
    changed = {k: [mine.get(k), theirs.get(k)] for k in sorted(set(mine) | set(theirs)) if mine.get(k) != theirs.get(k)}
    return {"folder": str(against), "changed_settings": changed,
            "comparisons": compare_runs(records, read_results(against))}


# The order of the planners in the report's tables (others after them, by name).
REPORT_ORDER = ("capplanner", "astar", "astar_learned")


def report_markdown(summary: dict) -> str:
    """The report as Markdown tables: per cell both planners' success and displacement ratio,
    the paired comparison, and the failure reasons."""
    def rate(row):
        return "-" if row is None or row["success_rate"] is None else \
            f"{row['successes']}/{row['tasks']} ({100 * row['success_rate']:.0f} %)"

    def ratio(row):
        return "-" if row is None or row["displacement_ratio"] is None else f"{row['displacement_ratio']:.3f}"

    by_cell = {(r["terrain"], r["difficulty"], r["planner"]): r for r in summary["rows"]}
    # Every planner the run walked, the paper's two first (a third arm, the learned A*, after).
    present = {r["planner"] for r in summary["rows"]}
    planners = [p for p in REPORT_ORDER if p in present] + sorted(present - set(REPORT_ORDER))
    names = [PLANNER_NAMES.get(p, p) for p in planners]
    lines = ["| terrain | difficulty | " + " | ".join(f"{n} success" for n in names) + " | "
             + " | ".join(f"{n} displacement ratio" for n in names) + " |",
             "| --- | --- |" + " --- |" * (2 * len(planners))]
    for terrain in TERRAINS:
        for difficulty in DIFFICULTIES:
            cells = [by_cell.get((terrain, difficulty, p)) for p in planners]
            if any(cells):
                lines.append(f"| {terrain} | {difficulty} | " + " | ".join(rate(c) for c in cells) + " | "
                             + " | ".join(ratio(c) for c in cells) + " |")
    for baseline, comparisons in (("astar", summary["comparisons"]), ("astar_learned", summary.get("comparisons_learned"))):
        if not comparisons:
            continue
        other = PLANNER_NAMES.get(baseline, baseline)
        lines += ["", f"| terrain | difficulty | paired tasks | both | only CapPlanner | only {other} | neither "
                      "| McNemar exact p |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for c in comparisons:
            lines.append(f"| {c['terrain']} | {c['difficulty']} | {c['tasks']} | {c['both']} | {c['only_capplanner']} "
                         f"| {c[f'only_{baseline}']} | {c['neither']} | {c['p_value']:.2g} |")
    claim = summary.get("claim")
    if claim:
        lo, hi = claim["difference_ci95"]
        rates = ", ".join(f"{d} {100 * r:.0f} % (aim {100 * claim['aims']['rates'][d]:.0f} %: "
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
                         f"{100 * CLAIM_POWER:.0f} %.")
                      + f" (The aims of issue {claim['aims']['issue']}.)"]
        if claim.get("simple_rates"):
            simple = claim["simple_rates"]
            lines += ["", f"Simple: CapPlanner {100 * simple['capplanner']:.0f} %, A* {100 * simple['astar']:.0f} % "
                          f"(aim at least {100 * claim['aims']['simple']:.0f} % each: "
                          f"{'met' if claim['simple_holds'] else 'missed'})."]
    if summary.get("routes"):
        lines += ["", "| planner | difficulty | walks | displacement ratio (walked) | back-outs per walk "
                      "| refusals gone round per walk | replans per walk "
                      "| replans changing the next 2 m without a refusal | topology changes per walk |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for row in summary["routes"]:
            changed = ("-" if row["changed_share"] is None else
                       f"{row['changed_replans']} ({100 * row['changed_share']:.1f} %)")
            shown = "-" if row["displacement_ratio"] is None else f"{row['displacement_ratio']:.3f}"
            name = PLANNER_NAMES.get(row["planner"], row["planner"])
            lines.append(f"| {name} | {row['difficulty']} | {row['walks']} | {shown} | {row['back_outs_per_walk']:.2f} "
                         f"| {row['recoveries_per_walk']:.2f} | {row['replans_per_walk']:.1f} | {changed} "
                         f"| {row['topology_changes_per_walk']:.2f} |")
    if summary.get("route_calibration"):
        lines += ["", "CapPlanner's first plans: the chance of no fall and of every action walking as the plan "
                      "weighs them (the ensemble's doubt, refusals counted as it is tuned to), and the model's own "
                      "estimate of no fall along the same route, its mean without doubt, refusals gone round "
                      "(expected), against the share walked.", "",
                  "| terrain | difficulty | CapPlanner set out | predicted no-fall | predicted success | expected "
                  "no-fall | walked | declined (no path) | of those, A* walked |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]

        def num(v):
            return "-" if v is None else f"{v:.2f}"

        for c in summary["route_calibration"]:
            lines.append(f"| {c['terrain']} | {c['difficulty']} | {c['started']}/{c['tasks']} "
                         f"| {num(c['predicted_fall_free'])} | {num(c.get('predicted_success'))} "
                         f"| {num(c.get('expected_fall_free'))} | {num(c['walked_rate'])} | {c['declined']} "
                         f"| {c['declined_walked_by_astar']} |")
        check = summary.get("route_calibration_check")
        if check and check["cells"]:
            parts = [f"{name} {check[field]['within']} of {check[field]['cells']} (worst {check[field]['worst_cell']}, "
                     f"off by {check[field]['worst_gap']:.2f}: {'met' if check[field]['holds'] else 'missed'})"
                     for field, name in ROUTE_PREDICTIONS.items() if field in check]
            lines += ["", f"Cells where CapPlanner's prediction is within {check['tolerance']:.2f} of the share it "
                          f"walked (the aim of issue {check['issue']}: every cell): "
                          + "; ".join(parts) + "."]
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
    scale = float(read_settings(out).get("scale", 1.0)) if scale is None else float(scale)
    tasks = discordant_tasks(records)
    for t in tasks:
        task = make_task(t["terrain"], t["difficulty"], t["seed"], scale=scale)
        t["picture"] = str(plot_task_pair(task, t["records"], folder / f"{t['task']}.png", title=t["task"]))
    return tasks
