"""``qz experiment capplanner-vs-astar``: paper 000 Fig. 9, and ``qz experiment tune-astar`` /
``tune-capplanner``, each planner's settings chosen on tuning worlds (see
qz_drake.experiments.fig9); ``score-missions``, a capability model against the missions of a
run's walks (qz_drake.experiments.walk_scores)."""

from __future__ import annotations

import json
from pathlib import Path

from qz_drake.cli.arguments import LEG_CLEARANCE_SOFTMIN, TERMINAL_STANCES, WALK_CONTROL_MODE, WALK_TIME_STEP


def _switches(text: str | None, flag: str) -> tuple[bool, ...] | None:
    """A comma-separated list of on/off values (on, off, true, false, 1, 0)."""
    from qz_drake.errors import bad_value

    if text is None:
        return None
    values = {"on": True, "true": True, "1": True, "off": False, "false": False, "0": False}
    words = [w.strip().lower() for w in text.split(",") if w.strip()]
    if not words or any(w not in values for w in words):
        raise bad_value(flag, text, "expected comma-separated on/off values")
    return tuple(values[w] for w in words)


def _names(text, field, valid) -> tuple[str, ...]:
    from qz_drake.cli.arguments import parse_names

    return parse_names(text, field, valid) or tuple(valid)


def run_fig9(args) -> int:
    from qz_drake.cli.arguments import parse_names
    from qz_drake.experiments.fig9 import EXPERIMENT_PLANNERS, PLANNERS, ExperimentConfig, run_experiment
    from qz_drake.experiments.plots import plot_fig9
    from qz_drake.experiments.worlds import DIFFICULTIES, TASKS_PER_CELL, TERRAINS

    from qz_drake.experiments.fig9 import astar_settings, capplanner_settings

    if args.tasks is None:
        args.tasks = TASKS_PER_CELL

    tuned = astar_settings(args.astar_tuning) if args.astar_tuning else {}
    if args.capplanner_tuning:
        tuned.update(capplanner_settings(args.capplanner_tuning))
    config = ExperimentConfig(capability_model=args.model or "", scale=args.scale,
                              recovery_back_out=not args.no_back_out,
                              capplanner_measured_stance=not args.no_measured_stance,
                              capplanner_refused_in_every_topology=not args.retry_other_topologies,
                              capplanner_hold_margin=_hold_margin(args),
                              capplanner_turns_with_moves=not args.turns_alone,
                              capplanner_turn_edge_risk=_turn_edge_risk(args),
                              capplanner_revisit_cost=_revisit_cost(args),
                              capplanner_target_shift=_target_shift(args),
                              capplanner_topologies=_topologies(args),
                              blc_retries=args.blc_retries, blc_ladder=args.blc_ladder, route_check=args.route_check,
                              blc_terminal_stance=args.terminal_stance,
                              control_mode=args.control_mode, time_step=args.time_step,
                              blc_leg_clearance_softmin=_leg_clearance_softmin(args),
                              astar_learned_weight=args.astar_learned_weight,
                              astar_learned_veto=args.astar_learned_veto,
                              record_missions=args.record_missions, **tuned)
    summary = run_experiment(args.out, planners=parse_names(args.planners, "--planners", tuple(PLANNERS))
                             or EXPERIMENT_PLANNERS,
                             terrains=_names(args.terrains, "--terrains", TERRAINS),
                             difficulties=_names(args.difficulties, "--difficulties", DIFFICULTIES),
                             tasks=args.tasks, workers=args.workers, ray_address=args.ray_address, config=config,
                             progress=not args.json, recordings=args.recordings, first_seed=args.first_seed)
    png = plot_fig9(summary["rows"], f"{args.out}/fig9.png", title="CapPlanner's TLC against A* (same BLC)")
    summary["figure"] = str(png)
    print(json.dumps(summary, indent=None if args.json else 2))
    return 0


def run_report(args) -> int:
    from qz_drake.experiments.fig9 import report, report_markdown

    if args.pictures and args.out is None:
        from qz_drake.errors import bad_value

        raise bad_value("--out", None, "needed by --pictures, which draws into a folder of its own (e.g. --out "
                                       "out/fig9_report; into the run's folder only where you name it)")
    if args.predict:
        from qz_drake.experiments.fig9 import predict_routes

        predict_routes(args.run, progress=not args.json)
    summary = report(args.run, against=args.against)
    if args.pictures:
        from qz_drake.experiments.fig9 import discordant_pictures

        summary["discordant"] = [{"task": t["task"], "walked": t["walked"], "failed": t["failed"],
                                  "reason": t["records"][t["failed"]]["reason"], "picture": t["picture"]}
                                 for t in discordant_pictures(args.run, folder=Path(args.out) / "discordant")]
    print(json.dumps(summary) if args.json else report_markdown(summary))
    return 0


def run_score_missions(args) -> int:
    from pathlib import Path

    from qz_drake.capability.model import CapabilityModel
    from qz_drake.errors import bad_value
    from qz_drake.experiments.fig9 import RESULTS, read_results, read_settings
    from qz_drake.experiments.walk_scores import score_missions

    folders = [Path(out) for out in args.out]
    for out in folders:
        if not (out / RESULTS).is_file():
            raise bad_value("results", str(out), f"no {RESULTS} there (run qz experiment capplanner-vs-astar)")
    settings = [read_settings(out) for out in folders]
    scales = {float(s.get("scale", 1.0)) for s in settings}
    if len(scales) > 1:
        raise bad_value("results", [str(out) for out in folders], f"worlds of other scales ({sorted(scales)})")
    model = CapabilityModel.load(args.model or settings[0].get("capability_model") or None)
    records = [r for out in folders for r in read_results(out)]
    scores = score_missions(records, model, scale=scales.pop())
    if args.json:
        print(json.dumps(scores))
        return 0

    def auc(name):
        m = scores.get(name)
        return "-" if not m or m["auc"] is None else f"{m['auc']:.3f} ({m['positives']} of {m['n']})"

    def num(v):
        return "-" if v is None else f"{v:.2f}"

    o = scores["outcomes"]
    print(f"{scores['missions']} missions of {scores['walks']} walks ({scores['walks_without_missions']} walks kept "
          f"none): walked {o['walked']}, no plan {o['no_plan']}, executed and failed {o['failed']}. ROC AUC of "
          f"P(executed and failed) {auc('failed')}, of P(no plan) {auc('no_plan')}, of P(walked) {auc('walked')}.")
    base = scores["baseline_auc"]
    print("The baseline (the largest height range of the mission's patches, no learning): ROC AUC "
          + ", ".join(f"{label} {'-' if base[k] is None else f'{base[k]:.3f}'}"
                      for k, label in (("failed", "executed and failed"), ("no_plan", "no plan"), ("walked", "walked")))
          + ".")
    print("\n| planner | terrain | difficulty | walks | without an execution failure | predicted | missions "
          "| walked | predicted |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for c in scores["cells"]:
        print(f"| {c['planner']} | {c['terrain']} | {c['difficulty']} | {c['walks']} "
              f"| {num(c['walks_without_execution_failure'])} | {num(c['predicted_without_execution_failure'])} "
              f"| {c['missions']} | {num(c['missions_walked'])} | {num(c['predicted_walked'])} |")
    return 0


def _numbers(text, field) -> tuple[float, ...] | None:
    from qz_drake.errors import bad_value

    if text is None:
        return None
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise bad_value(field, text, "expected comma-separated numbers") from None


def _print_tuning(report, args) -> None:
    if args.json:
        print(json.dumps(report))
        return
    for row in report["grid"]:
        setting = ", ".join(f"{k} {row[k]:g}" for k in report["chosen"])
        walked = f", {row['walked']} walked here" if "walked" in row else ""
        print(f"{setting}: {row['successes']}/{row['tasks']} succeeded{walked}")
    print(f"chosen: {report['chosen']}")
    margin = report.get("margin")
    if margin:
        print(f"margin over the runner-up {margin['runner_up']}: {margin['successes']} against "
              f"{margin['runner_up_successes']} successes; of {margin['tasks_both']} tasks, {margin['only_chosen']} "
              f"walked by the chosen only, {margin['only_runner_up']} by the runner-up only "
              f"(McNemar exact p = {margin['mcnemar_p']:.2g})")


def _check_tasks(args) -> None:
    from qz_drake.experiments.fig9 import TUNING_TASKS_PER_CELL

    if args.tasks is None:
        args.tasks = TUNING_TASKS_PER_CELL
    if args.tasks < 1:
        from qz_drake.errors import bad_value

        raise bad_value("--tasks", args.tasks, "must be a positive whole number")


def run_tune_astar(args) -> int:
    from qz_drake.experiments.fig9 import (TUNING_BODY_RADII, TUNING_SLOPES_DEG, TUNING_STEP_HEIGHTS,
                                           ExperimentConfig, tune_astar)
    from qz_drake.experiments.fig9 import TUNING_DIFFICULTIES
    from qz_drake.experiments.worlds import TERRAINS

    _check_tasks(args)
    report = tune_astar(args.out, step_heights=_numbers(args.steps, "--steps") or TUNING_STEP_HEIGHTS,
                        slopes_deg=_numbers(args.slopes, "--slopes") or TUNING_SLOPES_DEG,
                        body_radii=_numbers(args.radii, "--radii") or TUNING_BODY_RADII,
                        terrains=_names(args.terrains, "--terrains", TERRAINS),
                        difficulties=_names(args.difficulties, "--difficulties", TUNING_DIFFICULTIES),
                        tasks=args.tasks, workers=args.workers, ray_address=args.ray_address,
                        config=ExperimentConfig(scale=args.scale, recovery_back_out=not args.no_back_out,
                                                blc_retries=args.blc_retries, blc_ladder=args.blc_ladder,
                                                route_check=args.route_check,
                                                blc_terminal_stance=args.terminal_stance,
                                                control_mode=args.control_mode, time_step=args.time_step,
                                                blc_leg_clearance_softmin=_leg_clearance_softmin(args),
                                                record_missions=args.record_missions),
                        progress=not args.json)
    _print_tuning(report, args)
    return 0


def run_tune_capplanner(args) -> int:
    from qz_drake.experiments.fig9 import (TUNING_FAILURE_REWARDS, TUNING_MERGE_MIN_SUCCESS, TUNING_MISSION_LENGTHS,
                                           TUNING_PLAN_FAILURE_RISKS, TUNING_TOPOLOGY_CHANGE_COSTS,
                                           TUNING_PESSIMISMS, TUNING_TOPOLOGY_DOUBTS, ExperimentConfig,
                                           TUNING_DIFFICULTIES, tune_capplanner)
    from qz_drake.experiments.fig9.tune import TUNING_EDGE_COSTS
    from qz_drake.experiments.worlds import TERRAINS

    _check_tasks(args)
    report = tune_capplanner(
        args.out, failure_rewards=_numbers(args.failure_rewards, "--failure-rewards") or TUNING_FAILURE_REWARDS,
        topology_change_costs=_numbers(args.switch_costs, "--switch-costs") or TUNING_TOPOLOGY_CHANGE_COSTS,
        plan_failure_risks=_numbers(args.plan_failure_risks, "--plan-failure-risks") or TUNING_PLAN_FAILURE_RISKS,
        mission_lengths=_numbers(args.mission_lengths, "--mission-lengths") or TUNING_MISSION_LENGTHS,
        merge_min_success=_numbers(args.merge_thresholds, "--merge-thresholds") or TUNING_MERGE_MIN_SUCCESS,
        topology_doubts=_switches(args.topology_doubts, "--topology-doubts") or TUNING_TOPOLOGY_DOUBTS,
        pessimisms=_numbers(args.pessimisms, "--pessimisms") or TUNING_PESSIMISMS,
        edge_costs=_numbers(args.edge_costs, "--edge-costs") or TUNING_EDGE_COSTS,
        terrains=_names(args.terrains, "--terrains", TERRAINS),
        difficulties=_names(args.difficulties, "--difficulties", TUNING_DIFFICULTIES),
        tasks=args.tasks, workers=args.workers, ray_address=args.ray_address,
        config=ExperimentConfig(capability_model=args.model or "", scale=args.scale,
                                recovery_back_out=not args.no_back_out,
                                capplanner_measured_stance=not args.no_measured_stance,
                                capplanner_refused_in_every_topology=not args.retry_other_topologies,
                                capplanner_hold_margin=_hold_margin(args),
                                capplanner_turns_with_moves=not args.turns_alone,
                                capplanner_turn_edge_risk=_turn_edge_risk(args),
                                capplanner_revisit_cost=_revisit_cost(args),
                                capplanner_target_shift=_target_shift(args),
                                capplanner_topologies=_topologies(args),
                                blc_retries=args.blc_retries, blc_ladder=args.blc_ladder, route_check=args.route_check,
                                blc_terminal_stance=args.terminal_stance,
                                control_mode=args.control_mode, time_step=args.time_step,
                                blc_leg_clearance_softmin=_leg_clearance_softmin(args),
                                record_missions=args.record_missions),
        progress=not args.json)
    _print_tuning(report, args)
    return 0


def _tuning_arguments(p) -> None:
    p.add_argument("--out", required=True, help="tuning folder (one results folder per setting, tuning.json)")
    p.add_argument("--tasks", type=int, default=None,
                   help="tuning tasks per terrain and difficulty (default 4, fig9.TUNING_TASKS_PER_CELL)")
    p.add_argument("--terrains", default=None, help="comma-separated: stairs,obstacles,both")
    p.add_argument("--difficulties", default=None,
                   help="comma-separated: simple,medium,hard (default medium,hard: fig9.TUNING_DIFFICULTIES)")
    p.add_argument("--scale", type=float, default=1.0, help="world scale (1: the experiment's worlds)")
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--ray-address", default=None,
                   help="run the tasks on this Ray cluster (host:port), or on a Ray instance of --workers CPUs "
                        "that the command starts on this machine and stops at its end (local)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    _back_out_argument(p)


def _back_out_argument(p) -> None:
    p.add_argument("--no-back-out", action="store_true",
                   help="neither planner backs out of a dead end (walks as before session 38; "
                        "qz_drake.planning.back_out)")
    p.add_argument("--blc-retries", type=int, default=0,
                   help="solve a mission the BLC could not plan again up to N times, one tripod cycle longer "
                        "each time, for both planners (default 0: first solves only, as the capability trials)")
    p.add_argument("--route-check", type=int, default=0, metavar="N",
                   help="both planners plan the next N missions of every route with the walk's BLC before handing "
                        "it out and go round a refusal foreseen there (qz_drake.planning.route_check; default 0: "
                        "none)")
    p.add_argument("--record-missions", action="store_true",
                   help="keep every mission of each walk in its record, a refused one with the start the BLC was "
                        "given (qz experiment score-missions; benchmarks/blc_refusals.py replay)")
    p.add_argument("--control-mode", default=WALK_CONTROL_MODE,
                   help="how the joints are driven in every walk, for both planners: position (Eq. 7's PD in the "
                        "drives: the plant's implicit PD on the tracker's q and v; the default) or torque (Eq. 7 in "
                        "the controller, at steps of at most 2 ms; every run before issue 53's defaults), as a "
                        "dataset's trials")
    p.add_argument("--time-step", type=float, default=WALK_TIME_STEP,
                   help=f"the plant's step in every walk [s] (default {WALK_TIME_STEP:g}; torque: at most 0.002)")
    p.add_argument("--leg-clearance-softmin", default=str(LEG_CLEARANCE_SOFTMIN).lower(), metavar="S|none",
                   help="each leg's clearance in the BLC as one smooth minimum over its link points of sharpness S "
                        "[1/m] for both planners (BlcParameters.leg_clearance_softmin, e.g. 300), or none: a row per "
                        f"link point (default {str(LEG_CLEARANCE_SOFTMIN).lower()})")
    p.add_argument("--terminal-stance", choices=TERMINAL_STANCES, default="free",
                   help="where the feet stand when each mission ends, for both planners: free (as the BLC leaves "
                        "them) or canonical (the target's canonical stance, which CapPlanner's map then assumes; "
                        "qz_drake.trajopt.stance)")
    p.add_argument("--blc-ladder", default="",
                   help="solve a mission the BLC could not plan again on these rungs, in order, until one plans, "
                        "for both planners: cycles+N (N tripod cycles longer), split, split+N (two halves "
                        "chained), short (the target 0.1 m nearer), free (the end stance left to the BLC, for "
                        "--terminal-stance canonical), comma-separated; not with --blc-retries")


def _stance_argument(p) -> None:
    p.add_argument("--no-measured-stance", action="store_true",
                   help="CapPlanner judges every move by the map's nominal footholds, also from the stance the "
                        "robot stands in (walks as before session 38)")
    p.add_argument("--retry-other-topologies", action="store_true",
                   help="after the BLC refuses a move, CapPlanner may try it again in another topology (walks "
                        "as before session 39)")
    p.add_argument("--hold-margin", type=float, default=None,
                   help="a replan at a mission's end keeps CapPlanner's route unless the new one is worth more "
                        "than this (value units: the goal 100, an action 1); default: every replan takes the "
                        "policy's path")
    p.add_argument("--capplanner-topologies", default=None,
                   help="comma-separated topologies CapPlanner may plan in (default: every one its model knows; "
                        "nominal: it never changes topology)")
    p.add_argument("--turns-alone", action="store_true",
                   help="CapPlanner sends a turn in place as a mission of its own where the merge threshold "
                        "says so (walks as before session 52; default: a turn goes with the move after it, "
                        "guidance.MissionSplitConfig.turns_with_moves)")
    p.add_argument("--turn-edge-risk", type=float, default=None, metavar="R",
                   help="CapPlanner counts a turn from within 0.4 m of an edge as failing up to R of the time (on "
                        "the edge, falling to 0 at 0.4 m), whatever its model says "
                        "(CapabilityMdpConfig.turn_edge_risk; default: ExperimentConfig's)")
    p.add_argument("--revisit-cost", type=float, default=None, metavar="C",
                   help="a move into a cell costs CapPlanner C more (value units: the goal 100, an action 1) for "
                        "each mission that ended there (CapabilityVIPlanner's revisit_cost; default: "
                        "ExperimentConfig's)")
    p.add_argument("--target-shift", type=float, default=None, metavar="D",
                   help="CapPlanner's mission targets but the goal move up to D m from their cell's centre to the "
                        "point of its level clearest of edges (guidance.place_targets; default: ExperimentConfig's)")


def _turn_edge_risk(args) -> float:
    from qz_drake.experiments.fig9 import ExperimentConfig
    from qz_drake.planning.capability_mdp import check_turn_edge_risk

    if args.turn_edge_risk is None:
        return ExperimentConfig().capplanner_turn_edge_risk
    return check_turn_edge_risk(args.turn_edge_risk, "--turn-edge-risk")


def _revisit_cost(args) -> float:
    from qz_drake.experiments.fig9 import ExperimentConfig
    from qz_drake.planning.capability_planner import check_revisit_cost

    if args.revisit_cost is None:
        return ExperimentConfig().capplanner_revisit_cost
    return check_revisit_cost(args.revisit_cost, "--revisit-cost")


def _target_shift(args) -> float:
    from qz_drake.experiments.fig9 import ExperimentConfig
    from qz_drake.planning.guidance import check_target_shift

    if args.target_shift is None:
        return ExperimentConfig().capplanner_target_shift
    return check_target_shift(args.target_shift, "--target-shift")


def _topologies(args) -> str:
    from qz_drake.cli.arguments import parse_names
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    return ",".join(parse_names(args.capplanner_topologies, "--capplanner-topologies", TOPOLOGY_NAMES) or ())


def _leg_clearance_softmin(args) -> float | None:
    """--leg-clearance-softmin: a sharpness, or none (a row per link point); its errors name the
    option."""
    from qz_drake.errors import QzError, bad_value
    from qz_drake.trajopt.parameters import BlcParameters

    text = str(args.leg_clearance_softmin).strip()
    if text.lower() == "none":
        return None
    try:
        sharpness = float(text)
    except ValueError:
        raise bad_value("--leg-clearance-softmin", args.leg_clearance_softmin,
                        "expected a sharpness in 1/m or none") from None
    try:
        BlcParameters(leg_clearance_softmin=sharpness)
    except QzError as error:
        raise bad_value("--leg-clearance-softmin", args.leg_clearance_softmin,
                        "must be a positive finite sharpness [1/m] or none") from error
    return sharpness


def _hold_margin(args) -> float | None:
    from qz_drake.planning.capability_planner import check_hold_margin

    return check_hold_margin(args.hold_margin, "--hold-margin")


def register(subparsers) -> None:
    """Adds ``experiment`` (capplanner-vs-astar) to the ``qz`` command."""
    experiment = subparsers.add_parser("experiment", help="long experiments that compare planners")
    sub = experiment.add_subparsers(dest="experiment_command", required=True, parser_class=type(experiment))
    p = sub.add_parser("capplanner-vs-astar", help="paper 000 Fig. 9: the learned TLC against A*")
    p.add_argument("--out", required=True, help="results folder (results.jsonl, results.csv/json, fig9.png)")
    p.add_argument("--tasks", type=int, default=None,
                   help="tasks per terrain and difficulty (default 50, worlds.TASKS_PER_CELL: 80 %% power for "
                        "the aim)")
    p.add_argument("--terrains", default=None, help="comma-separated: stairs,obstacles,both")
    p.add_argument("--difficulties", default=None, help="comma-separated: simple,medium,hard")
    p.add_argument("--planners", default=None,
                   help="comma-separated: capplanner, astar, astar_learned (A* with the capability model as an edge "
                        "cost and veto; --astar-learned-weight, --astar-learned-veto) (default capplanner,astar)")
    p.add_argument("--astar-learned-weight", type=float, default=3.0,
                   help="astar_learned: cost per unit of -log of a grid move's predicted success (default 3, "
                        "chosen on the tuning worlds)")
    p.add_argument("--astar-learned-veto", type=float, default=0.0,
                   help="astar_learned: least predicted success of a grid move it may take (default 0: none)")
    p.add_argument("--model", default=None, help="CapPlanner's capability model folder (default: shipped)")
    p.add_argument("--astar-tuning", default=None,
                   help="tuning.json (or its folder) of qz experiment tune-astar: A*'s chosen thresholds "
                        "(default: the untuned defaults)")
    p.add_argument("--capplanner-tuning", default=None,
                   help="tuning.json (or its folder) of qz experiment tune-capplanner: CapPlanner's chosen "
                        "failure reward and topology-change cost (default: the MDP's defaults)")
    p.add_argument("--scale", type=float, default=1.0, help="world scale (1: the experiment's worlds)")
    p.add_argument("--first-seed", type=int, default=0,
                   help="the worlds' first seed (0: the experiment's 0-49; 100: the fresh run's 100-149; 500-999 "
                        "validation; from 16777216 = 2^24 training worlds, whose walks collect-routes learns from; "
                        "50-99 are refused)")
    p.add_argument("--recordings", type=int, default=1,
                   help="record the first N tasks of every terrain, difficulty and planner (out/recordings/)")
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--ray-address", default=None,
                   help="run the tasks on this Ray cluster (host:port), or on a Ray instance of --workers CPUs "
                        "that the command starts on this machine and stops at its end (local)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    _back_out_argument(p)
    _stance_argument(p)
    p.set_defaults(func=run_fig9)

    p = sub.add_parser("report", help="the tables of a capplanner-vs-astar results folder (a run in progress too)")
    p.add_argument("run", help="results folder of qz experiment capplanner-vs-astar (read; --predict adds its "
                               "predictions.jsonl there)")
    p.add_argument("--json", action="store_true", help="print one JSON line instead of Markdown tables")
    p.add_argument("--against", default=None,
                   help="another results folder of the same worlds (an earlier model, BLC or tuning): "
                        "each planner paired with its own walks there")
    p.add_argument("--predict", action="store_true",
                   help="first replan every CapPlanner task from its start with the run's model and settings "
                        "(predictions.jsonl in RUN, resumable; minutes) to add the route calibration table")
    p.add_argument("--pictures", action="store_true",
                   help="draw every discordant task (one planner walked it, the other did not): both walked "
                        "paths and where the failed one stopped, as OUT/discordant/<task>.png (needs --out)")
    p.add_argument("--out", default=None,
                   help="folder for the --pictures (e.g. out/fig9_report; the run's own folder rewrites the "
                        "pictures shipped there)")
    p.set_defaults(func=run_report)

    p = sub.add_parser("score-missions", help="a capability model against the missions of a run's walks "
                                              "(a run with record_missions; issue 37)")
    p.add_argument("out", nargs="+", help="results folders whose walks kept their missions (scored together)")
    p.add_argument("--model", default=None, help="capability model folder (default: the run's, else the shipped one)")
    p.add_argument("--json", action="store_true", help="print one JSON line instead of the table")
    p.set_defaults(func=run_score_missions, out_kind=None)

    p = sub.add_parser("tune-astar", help="choose the A* baseline's thresholds on tuning worlds "
                                          "(seeds from 1000, never the experiment's)")
    _tuning_arguments(p)
    p.add_argument("--steps", default=None, help="comma-separated max step heights [m] (default 0.12,0.16,0.2,0.24)")
    p.add_argument("--slopes", default=None, help="comma-separated max slopes [deg] (default 20,30)")
    p.add_argument("--radii", default=None,
                   help="comma-separated body-disc radii of the cost map [m] (default 0.7,0.9)")
    p.set_defaults(func=run_tune_astar)

    p = sub.add_parser("tune-capplanner", help="choose CapPlanner's failure reward, refusal risk, longest mission "
                                               "and merge threshold on the same tuning worlds as A*'s")
    _tuning_arguments(p)
    p.add_argument("--failure-rewards", default=None,
                   help="comma-separated failure rewards, negative (default -100,-200; the goal is +100)")
    p.add_argument("--switch-costs", default=None, help="comma-separated topology-change costs (default 2)")
    p.add_argument("--plan-failure-risks", default=None,
                   help="comma-separated shares of predicted planning failures counted as falls, in [0, 1] "
                        "(default 0,1: the model's split, every refusal a fall)")
    p.add_argument("--mission-lengths", default=None,
                   help="comma-separated longest missions of CapPlanner's split [m] (default 1.5,2)")
    p.add_argument("--merge-thresholds", default=None,
                   help="comma-separated least predicted success of a merged mission (default 0.8,0.95)")
    p.add_argument("--topology-doubts", default=None,
                   help="comma-separated on/off: doubt a topology change by the ensemble's disagreement about the "
                        "difference (default on)")
    p.add_argument("--pessimisms", default=None,
                   help="comma-separated doubts of an action's success by the ensemble's spread, p - pessimism x "
                        "spread (default 1)")
    p.add_argument("--edge-costs", default=None,
                   help="comma-separated costs of a move or turn that passes near an edge (a step's riser, a box's "
                        "side), in value units at the edge, falling to 0 at 0.5 m (CapabilityMdpConfig.edge_cost; "
                        "default 0: none)")
    p.add_argument("--model", default=None, help="CapPlanner's capability model folder (default: shipped)")
    _stance_argument(p)
    p.set_defaults(func=run_tune_capplanner)
