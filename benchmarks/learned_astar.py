"""The learned A* on the tuning tasks (issue 54's baseline from the field): A*'s geometric search
with CapPlanner's capability model as an edge cost and veto (planner ``astar_learned``,
``qz_drake.experiments.astar_baseline.LearnedCost``), walked in Drake on the 24 medium and hard
tuning tasks (seeds 1000-1003; ``--first-seed 500``: validation worlds) at A*'s tuned thresholds,
with the BLC and recovery of the runs it is compared with (``--planner astar`` or ``capplanner``:
the geometric A* or CapPlanner at its tuned setting, ``data/capplanner_tuning``, on the same
worlds and settings):

    python benchmarks/learned_astar.py OUT [--weight 3] [--veto 0] [--blc-ladder LADDER]
        [--terminal-stance free|canonical] [--workers 2] [--first-seed 1000] [--planner astar|capplanner]
        [--model DIR] [--route-check N] [--turns-alone] [--turn-edge-risk R]
        [--revisit-cost C] [--target-shift D]
    python benchmarks/learned_astar.py --table RUN [RUN ...]

OUT is a Fig. 9 results folder (resumable). ``--table`` prints, per results folder, the tasks
walked (medium / hard), refusals heard, refusals the route check foresaw, walks that spent all four, back-outs and the
displacement ratio, and which tasks each folder alone walked against the first. Worlds of seeds
50-99 are refused.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ASTAR_TUNING = "data/astar_tuning"
CAPPLANNER_TUNING = "data/capplanner_tuning"


def walk(out: Path, weight: float, veto: float, ladder: str, stance: str, workers: int, first_seed: int,
         planner: str = "astar_learned", model: str = "", route_check: int = 0,
         turns_with_moves: bool = True, turn_edge_risk: float = 0.0, revisit_cost: float = 0.0,
         target_shift: float = 0.0) -> dict:
    from qz_drake.experiments.fig9 import ExperimentConfig, astar_settings, capplanner_settings, run_experiment
    from qz_drake.experiments.fig9.tune import TUNING_DIFFICULTIES, TUNING_TASKS_PER_CELL
    from qz_drake.experiments.worlds import TERRAINS

    if first_seed <= 99 and first_seed + TUNING_TASKS_PER_CELL > 50:
        raise SystemExit(f"--first-seed {first_seed}: seeds 50-99 are kept for checks outside the project")
    config = ExperimentConfig(blc_ladder=ladder, blc_terminal_stance=stance, record_missions=True,
                              capability_model=model, route_check=route_check,
                              capplanner_turns_with_moves=turns_with_moves, capplanner_turn_edge_risk=turn_edge_risk,
                              capplanner_revisit_cost=revisit_cost, capplanner_target_shift=target_shift,
                              astar_learned_weight=weight, astar_learned_veto=veto, **astar_settings(ASTAR_TUNING),
                              **capplanner_settings(CAPPLANNER_TUNING))
    return run_experiment(out, planners=(planner,), terrains=TERRAINS, difficulties=TUNING_DIFFICULTIES,
                          tasks=TUNING_TASKS_PER_CELL, workers=workers, config=config, progress=True,
                          first_seed=first_seed, recordings=0)


def _records(run: Path) -> dict:
    """A results folder's records (or its tuning's one setting's) by task, the planner left out."""
    from qz_drake.experiments.fig9 import read_results

    folders = sorted({f.parent for f in run.rglob("results.jsonl")})
    if len(folders) != 1:
        raise SystemExit(f"{run}: expected one results folder, found {len(folders)}")
    return {r["key"].rsplit("-", 1)[0]: r for r in read_results(folders[0]) if r.get("reason") != "error"}


def table(runs) -> str:
    loaded = [(run, _records(run)) for run in runs]
    lines = ["| run | planner | walked (medium / hard) | refusals heard | foreseen | spent all four | back-outs "
             "| displacement medium / hard | walked where the first did not / not where it did |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    first = loaded[0][1]
    for run, records in loaded:
        rs = list(records.values())

        def count(difficulty):
            return sum(r["success"] for r in rs if r["difficulty"] == difficulty)

        disp = [np.mean([r["displacement_ratio"] for r in rs if r["success"] and r["difficulty"] == d] or [np.nan])
                for d in ("medium", "hard")]
        gained = sorted(k for k, r in records.items() if r["success"] and k in first and not first[k]["success"])
        lost = sorted(k for k, r in records.items() if not r["success"] and k in first and first[k]["success"])
        lines.append(f"| {run} | {rs[0]['planner']} | {sum(r['success'] for r in rs)} ({count('medium')} / "
                     f"{count('hard')}) | {sum(r['recoveries'] for r in rs)} | {sum(r.get('foreseen', 0) for r in rs)} | "
                     f"{sum(1 for r in rs if r['recoveries'] >= 4)} | {sum(r['back_outs'] for r in rs)} | "
                     f"{disp[0]:.3f} / {disp[1]:.3f} | {', '.join(gained) or '-'} / {', '.join(lost) or '-'} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", nargs="?", type=Path)
    parser.add_argument("--weight", type=float, default=3.0)
    parser.add_argument("--veto", type=float, default=0.0)
    parser.add_argument("--blc-ladder", default="cycles+1,split,split+1,cycles+2")
    parser.add_argument("--terminal-stance", choices=("free", "canonical"), default="free")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--first-seed", type=int, default=1000,
                        help="the worlds' first seed (1000: the tuning worlds; 500-999: validation)")
    parser.add_argument("--planner", choices=("astar_learned", "astar", "capplanner"), default="astar_learned",
                        help="astar, capplanner: the geometric A* or CapPlanner (at its tuned setting) beside it, "
                             "on the same worlds and settings")
    parser.add_argument("--model", default="", help="the capability model folder (default: the shipped one)")
    parser.add_argument("--route-check", type=int, default=0, metavar="N",
                        help="plan the next N missions of every route with the walk's BLC before walking it "
                             "(qz_drake.planning.route_check; default 0: none)")
    parser.add_argument("--turns-alone", action="store_true",
                        help="CapPlanner sends turns in place alone where its merge threshold says so (as "
                             "before session 52; guidance.MissionSplitConfig.turns_with_moves)")
    parser.add_argument("--turn-edge-risk", type=float, default=0.0, metavar="R",
                        help="CapPlanner counts a turn beside an edge as failing up to R of the time "
                             "(CapabilityMdpConfig.turn_edge_risk; default 0: the model's turns)")
    parser.add_argument("--revisit-cost", type=float, default=0.0, metavar="C",
                        help="a move into a cell costs CapPlanner C more for each mission that ended there "
                             "(CapabilityVIPlanner's revisit_cost; default 0: none)")
    parser.add_argument("--target-shift", type=float, default=0.0, metavar="D",
                        help="CapPlanner's mission targets move up to D m from their cell's centre, away from "
                             "edges (CapabilityVIPlanner's target_shift; default 0: the centres)")
    parser.add_argument("--table", nargs="+", type=Path, default=None, metavar="RUN")
    args = parser.parse_args(argv)
    if args.table:
        print(table(args.table))
        return 0
    if args.out is None:
        parser.error("give OUT, or --table RUN ...")
    summary = walk(args.out, args.weight, args.veto, args.blc_ladder, args.terminal_stance, args.workers,
                   args.first_seed, args.planner, args.model, args.route_check, not args.turns_alone,
                   args.turn_edge_risk, args.revisit_cost, args.target_shift)
    print(json.dumps({k: summary[k] for k in ("ran", "reused", "already_done", "wall_time_s", "out")}))
    print(table([args.out]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
