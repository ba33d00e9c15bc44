"""The paired comparison of the Fig. 9 planners on the same tasks (paper 000's claim, made
testable): success and displacement ratio per cell, McNemar's exact test of the paired walks,
the aim of issue 38 checked with the design's power, and each planner against itself in
another run of the same worlds.
"""

from __future__ import annotations

import numpy as np

from qz_drake.experiments.worlds import DIFFICULTIES, TERRAINS


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
# Issue 55's aims for the run on fresh worlds (seeds FRESH_SEEDS): the same difference, CapPlanner
# at least FRESH_CLAIM_RATES, on simple both planners at least SIMPLE_CLAIM_RATE, and in every
# (terrain, difficulty) cell CapPlanner's predicted route success within ROUTE_TOLERANCE of the
# share it walked (qz experiment report --predict).
FRESH_SEEDS = range(100, 150)
FRESH_CLAIM_RATES = {"medium": 0.95, "hard": 0.60}
SIMPLE_CLAIM_RATE = 0.98
ROUTE_TOLERANCE = 0.10


def claim_aims(records: list[dict]) -> dict:
    """The aims a run is judged by: issue 55's where every task is on a fresh world (FRESH_SEEDS),
    issue 38's otherwise (the decisive run's, and any other run's). ``rates`` CapPlanner's least
    success per difficulty; ``simple`` both planners' least success on simple; ``route_tolerance``
    the largest gap allowed between CapPlanner's predicted route success and its walked share in
    a cell (None: no aim)."""
    fresh = bool(records) and all(int(r["seed"]) in FRESH_SEEDS for r in records)
    if fresh:
        return {"issue": 55, "rates": dict(FRESH_CLAIM_RATES), "simple": SIMPLE_CLAIM_RATE,
                "route_tolerance": ROUTE_TOLERANCE}
    return {"issue": 38, "rates": dict(CLAIM_RATES), "simple": None, "route_tolerance": None}


def claim_check(records: list[dict]) -> dict | None:
    """The aim, checked on a run: on medium + hard pooled (paired tasks), both planners'
    success, the difference with its 95 % Wald interval for paired proportions, McNemar's exact
    p; CapPlanner's rate per difficulty against the run's aims (:func:`claim_aims`); on simple,
    with issue 55's aims, both planners' rates; whether each part holds; and the design's power:
    the share of discordant tasks, the power of this many paired tasks to find CLAIM_DIFFERENCE
    at CLAIM_ALPHA, and the tasks per cell that would give CLAIM_POWER."""
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
    aims = claim_aims(records)
    rates = {d: (rows[("all", d)]["capplanner_successes"] / rows[("all", d)]["tasks"]) if ("all", d) in rows else None
             for d in aims["rates"]}
    simple = None
    if aims["simple"] is not None and ("all", "simple") in rows:
        row = rows[("all", "simple")]
        simple = {planner: row[f"{planner}_successes"] / row["tasks"] for planner in ("capplanner", "astar")}
    discordant = (b + c_) / n
    per_cell = len(cells)
    needed = (pairs_for_power(discordant, CLAIM_DIFFERENCE, alpha=CLAIM_ALPHA, power=CLAIM_POWER)
              if discordant >= CLAIM_DIFFERENCE else None)
    return {"tasks": n, "capplanner_rate": cap, "astar_rate": astar, "difference": difference,
            "difference_ci95": [difference - half, difference + half], "only_capplanner": b, "only_astar": c_,
            "p_value": p, "difference_holds": bool(difference >= CLAIM_DIFFERENCE and p < CLAIM_ALPHA),
            "aims": aims, "capplanner_rates": rates,
            "rates_hold": {d: (r is not None and r >= aims["rates"][d]) for d, r in rates.items()},
            "simple_rates": simple,
            "simple_holds": None if simple is None else all(r >= aims["simple"] for r in simple.values()),
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
