"""``qz capability ...``: the capability pipeline of paper 000 II-E.1 on the command line.

``collect`` runs (or resumes) BLC trials into a dataset folder, on local processes or a Ray
cluster; ``stats`` summarises a dataset; ``recertify`` re-runs a sample of its trials after a
change to the code that should not change behaviour, and moves the manifest to the new code
only if every record comes out identical.

``train --dataset DIR --out DIR [--json] [--restart]`` trains the 18 networks on a trial
dataset (split by scene), writes the model directory (safetensors + JSON cards) with
``reliability.png`` and ``confusion.png`` of the test scenes, and prints the metrics table (or
one JSON line). Each network is kept as soon as it is trained: after Ctrl-C the same command
trains only the missing ones. ``--learner boosted [--members N]`` trains instead one
gradient-boosted ensemble for every topology and kind (qz_drake.capability.boosted: three
outcomes, ``boosted.npz`` + ``model.json``) and prints its test scores per network.

``evaluate [--model DIR] --dataset DIR [--json] [--out DIR]`` scores a model on every trial of
a dataset whose fingerprints are the model's; the JSON has one entry per network with
topology, kind, n, positives, auc, brier, ece, ece_floor (the ECE a calibrated model would
score on so few trials), accuracy.

``map --model DIR --terrain NAME|FILE --topology T --out FILE.png`` draws the predicted success
of moving forward from every 1 m cell and heading over the heightmap.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import sys
from pathlib import Path

from qz_drake.cli.arguments import (TERMINAL_STANCES, WALK_CONTROL_MODE, WALK_TIME_STEP, LazyText, one_of,
                                    parse_names, terrain_names, topology_names)
from qz_drake.errors import bad_value

# qz_drake.capability.collect.PROTOCOLS, here so that building the parser does not import the
# trials (pydrake); tests/test_cli_imports.py keeps the two the same.
PROTOCOLS = ("moves", "episodes", "plans")
LEARNERS = ("cnn", "boosted")
# The finest plant step a collection may take. [s]
MIN_TIME_STEP = 1e-4
# The largest boosted ensemble and learner: 20 and 25 times the defaults (5 members, 400 iterations).
MAX_MEMBERS = 100
MAX_BOOSTING_ITERATIONS = 10_000
SUMMARY_KEYS = ("topology", "kind", "n", "positives", "auc", "brier", "ece", "ece_floor", "accuracy")


def _kinds() -> tuple[str, ...]:
    from qz_drake.capability.patches import KINDS

    return KINDS


def _check_run(args) -> None:
    """A collection's run options (_run_arguments) and, where it has them, its plant step."""
    if args.workers < 1:
        raise bad_value("--workers", args.workers, "must be at least 1")
    if not args.log_every >= 0:
        raise bad_value("--log-every", args.log_every, "must be 0 (off) or a number of seconds")
    if hasattr(args, "time_step") and not args.time_step >= MIN_TIME_STEP:  # NaN too
        raise bad_value("--time-step", args.time_step, f"must be at least {MIN_TIME_STEP:g} s, a twentieth of the "
                                                       f"default: finer steps make a trial's seconds millions of steps")


def _run_options(args) -> dict:
    """The keyword arguments every collection takes from _run_arguments and the command line."""
    return dict(workers=args.workers, shard_size=args.shard_size, limit=args.limit, log_every=args.log_every,
                progress=not args.json and sys.stderr.isatty() or args.progress,
                command="qz " + " ".join(shlex.quote(a) for a in sys.argv[1:]))


def _trial_config(args, **more):
    """The TrialConfig of _label_arguments' options."""
    from qz_drake.capability.trials import TrialConfig

    return TrialConfig(control_mode=args.control_mode, time_step=args.time_step,
                       blc_terminal_stance=args.terminal_stance, blc_ladder=args.blc_ladder, **more)


def _protocol_hooks(dataset):
    """The RecertifyHooks of a dataset whose specs come from walks' records (protocol "routes",
    qz_drake.experiments.route_episodes), else None."""
    from qz_drake.capability.dataset import read_manifest

    if read_manifest(dataset).get("settings", {}).get("protocol") != "routes":
        return None
    from qz_drake.experiments.route_episodes import recertify_hooks

    return recertify_hooks()


def run_collect(args) -> int:
    if args.scenes < 1:
        raise bad_value("--scenes", args.scenes, "must be a positive whole number")
    if args.headings < 1:
        raise bad_value("--headings", args.headings, "must be at least 1")
    _check_run(args)
    from qz_drake.capability.collect import collect

    summary = collect(args.out, seed=args.seed, scenes=args.scenes,
                      topologies=parse_names(args.topologies, "--topologies", topology_names()),
                      kinds=parse_names(args.kinds, "--kinds", _kinds()),
                      config=_trial_config(args, headings_per_scene=args.headings), ray_address=args.ray_address,
                      protocol=args.protocol, **_run_options(args))
    print(json.dumps(dataclasses.asdict(summary), indent=None if args.json else 2))
    return 0


def run_collect_routes(args) -> int:
    _check_run(args)
    from qz_drake.experiments.route_episodes import collect_route_episodes

    summary = collect_route_episodes(args.out, args.walks, seed=args.seed, config=_trial_config(args),
                                     ray_address=args.ray_address, **_run_options(args))
    print(json.dumps(dataclasses.asdict(summary), indent=None if args.json else 2))
    return 0


def run_relabel(args) -> int:
    _check_run(args)
    from qz_drake.capability.relabel import relabel

    summary = relabel(args.dataset, args.out, blc_ladder=args.blc_ladder, verify=args.verify,
                      hooks=_protocol_hooks(args.dataset), **_run_options(args))
    print(json.dumps(dataclasses.asdict(summary), indent=None if args.json else 2))
    return 0


def run_stats(args) -> int:
    from qz_drake.capability import stats

    summary = stats.dataset_stats(args.dataset)
    if args.against:
        summary["against"] = stats.paired_against(args.dataset, args.against)
    if args.json:
        print(json.dumps(summary))
        return 0
    if args.markdown:
        print(stats.stats_markdown(summary))
        return 0
    print(f"{summary['dataset']}: {summary['executed']} executed, {summary['invalid_starts']} invalid starts, "
          f"{summary['errors']} errors, {summary['successes']} successes"
          + (f"; {summary['blc_only']} labelled by the BLC alone, {summary['blc_only_planned']} planned"
             if summary.get("blc_only") else ""))
    for row in summary["rows"]:
        rate = "-" if row["success_rate"] is None else f"{100 * row['success_rate']:.0f} %"
        print(f"  {row['topology']:>13} {row['kind']:>10}: {row['successes']}/{row['executed']} ({rate}), "
              f"BLC alone {row['blc_successes']}, errors {row['errors']}"
              + (f", planned without walking {row['blc_only_planned']}/{row['blc_only']}"
                 if row.get("blc_only") else ""))
    if summary["stairs_up"]:
        print("  up stairs (orthogonal and diagonal moves), per rise and topology:")
        for row in summary["stairs_up"]:
            low, high = row["rise_m"]
            lo, hi = row["ci95"]
            print(f"    {low:.2f}-{high:.2f} m {row['topology']:>13}: {row['successes']}/{row['executed']} "
                  f"({100 * row['success_rate']:.0f} %, 95 % CI {100 * lo:.0f}-{100 * hi:.0f} %)")
    if summary.get("against"):
        print(f"  against {summary['against']['other']} (the trials executed in both):")
        for row in summary["against"]["rows"]:
            print(f"    {row['group']:>18}: {row['successes']}/{row['trials']} here, {row['other_successes']} there "
                  f"(only here {row['only_this']}, only there {row['only_other']}, McNemar p {row['p_value']:.2g})")
    return 0


def run_recertify(args) -> int:
    from qz_drake.capability.collect import recertify

    result = recertify(args.dataset, sample=args.sample, workers=args.workers,
                       command="qz " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
                       reference_code=args.reference_code, hooks=_protocol_hooks(args.dataset))
    if args.json:
        print(json.dumps(dataclasses.asdict(result)))
    elif not result.changed:
        print(f"{result.dataset}: the code's fingerprints are the dataset's; nothing to certify")
    elif result.identical:
        print(f"{result.dataset}: {', '.join(result.changed)} changed; {result.rerun} {result.unit} re-run, "
              f"every record the same (labels and inputs equal, successful walks' measurements "
              f"within 2 %; largest relative difference of any measurement "
              f"{result.largest_relative_difference:.1e}): the manifest now names this code "
              f"({result.fingerprint_after})"
              + (f"; {len(result.machine_differences)} differed from the stored record the same way with the "
                 f"certified code on this machine (the collecting processor's, listed in the manifest)"
                 if result.machine_differences else ""))
    else:
        first = result.mismatches[0]
        print(f"{result.dataset}: {', '.join(result.changed)} changed; {len(result.mismatches)} of "
              f"{result.rerun} re-run {result.unit} differ ({result.unit[:-1]} {first['index']}"
              f"{'' if 'mission' not in first else ', mission ' + str(first['mission'])}: {', '.join(first['fields'])}): "
              f"the labels describe other behaviour; collect a new dataset"
              + ("" if args.reference_code else
                 " (or, if the records came from another processor, compare with the certified code on this "
                 "machine: --reference-code DIR)"))
    return 0 if result.identical else 1


def _label_arguments(p) -> None:
    """The options of a collection that decide its labels (TrialConfig's)."""
    p.add_argument("--control-mode", default=WALK_CONTROL_MODE,
                   help="how the joints are driven: position (Eq. 7's PD in the drives: the plant's implicit PD on "
                        "the tracker's q and v; the walks' default) or torque (Eq. 7 in the controller, at 2 ms "
                        "steps; every dataset before issue 53's defaults)")
    p.add_argument("--time-step", type=float, default=WALK_TIME_STEP,
                   help=f"the plant's step [s] (default {WALK_TIME_STEP:g}; torque: at most 0.002)")
    p.add_argument("--terminal-stance", choices=TERMINAL_STANCES, default="free",
                   help="where the feet stand when each mission ends: free (as the BLC leaves them) or canonical "
                        "(the target's canonical stance, qz_drake.trajopt.stance)")
    p.add_argument("--blc-ladder", default="", metavar="RUNGS",
                   help="a refused mission is solved again on these rungs before it is labelled not planned, as "
                        "the walks' BLC does (e.g. cycles+1,split,split+1,cycles+2; default: the first solve only)")


def _run_arguments(p, unit: str) -> None:
    """The options of how a collection runs, where it stores and what it prints."""
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--shard-size", type=int, default=100, help="records per shard file")
    p.add_argument("--limit", type=int, default=None, help=f"stop after this many new {unit}")
    p.add_argument("--progress", action="store_true", help="show the progress display even when not on a terminal")
    p.add_argument("--log-every", type=float, default=0.0, metavar="SECONDS",
                   help="print a plain progress line on stderr at most this often (background runs)")
    p.add_argument("--json", action="store_true", help="print one JSON line")


def register(subparsers) -> None:
    """Adds ``capability`` (collect, stats, and the model commands) to the ``qz`` command."""
    capability = subparsers.add_parser("capability", help="capability trials, dataset and model (paper 000)")
    sub = capability.add_subparsers(dest="capability_command", required=True, parser_class=type(capability))

    p = sub.add_parser("collect", help="run (or resume) BLC trials into a dataset folder")
    p.add_argument("--out", required=True, help="dataset folder (manifest.json + shards)")
    p.add_argument("--scenes", type=int, default=1000, help="number of scenes (paper 000: 1000)")
    p.add_argument("--headings", type=int, default=1, help="heading samples per scene (each in every topology and kind)")
    p.add_argument("--topologies", default=None,
                   help=LazyText(lambda: f"comma-separated topologies, each {one_of(topology_names())} "
                                         f"(default: all)"))
    p.add_argument("--kinds", default=None,
                   help=LazyText(lambda: f"comma-separated kinds, each {one_of(_kinds())} (default: all)"))
    p.add_argument("--protocol", default="moves", choices=PROTOCOLS,
                   help="moves: one-move trials from a standing start (paper 000), every topology and "
                        "kind per scene; episodes: per scene and topology a chain of the planner's "
                        "actions walked like a walk, a record per mission (issue 37); plans: per scene "
                        "and topology a chain of such actions planned by the BLC one after the other and "
                        "never walked, a record per mission labelled by the BLC alone (status blc_only)")
    _label_arguments(p)
    p.add_argument("--ray-address", default=None,
                   help="run the trials on this Ray cluster (host:port), or on a Ray instance of --workers CPUs "
                        "that the command starts on this machine and stops at its end (local)")
    p.add_argument("--seed", type=int, default=0)
    _run_arguments(p, "trials")
    p.set_defaults(func=run_collect)

    p = sub.add_parser("collect-routes", help="run (or resume) episodes from the stances the planners' own walks "
                                              "stood in, on their training worlds (issue 54; a dataset as collect's)")
    p.add_argument("--walks", required=True, nargs="+", metavar="RUN",
                   help="folders of qz experiment walks with --record-missions on training worlds (seeds from "
                        "2^24); every mission start they recorded starts an episode")
    p.add_argument("--out", required=True, help="dataset folder (manifest.json + shards)")
    _label_arguments(p)
    p.add_argument("--ray-address", default=None,
                   help="run the episodes on this Ray cluster (host:port), or on a Ray instance of --workers CPUs "
                        "that the command starts on this machine and stops at its end (local)")
    p.add_argument("--seed", type=int, default=0, help="draws the actions after each route's own")
    _run_arguments(p, "episodes")
    p.set_defaults(func=run_collect_routes)

    p = sub.add_parser("relabel", help="an episode dataset labelled again with the walks' BLC ladder: episodes that "
                                       "refused and failed nothing copied (a sample walked again to check), the "
                                       "others walked again (resumable)")
    p.add_argument("dataset", help="the episode (or route-episode) dataset folder")
    p.add_argument("--out", required=True, help="the new dataset folder")
    p.add_argument("--blc-ladder", required=True, metavar="RUNGS",
                   help="the ladder to label with (e.g. cycles+1,split,split+1,cycles+2, the tuned walks')")
    p.add_argument("--verify", type=int, default=12,
                   help="episodes to be copied that are walked again first and must come out the same (default 12)")
    _run_arguments(p, "episodes")
    p.set_defaults(func=run_relabel)

    p = sub.add_parser("stats", help="summarise a capability dataset")
    p.add_argument("dataset", help="dataset folder")
    output = p.add_mutually_exclusive_group()
    output.add_argument("--json", action="store_true", help="print one JSON line")
    output.add_argument("--markdown", action="store_true", help="print the summary as Markdown tables")
    p.add_argument("--against", default=None, metavar="DIR",
                   help="another dataset of the same trials (the same seed, e.g. collected with another BLC): "
                        "the trials executed in both, paired, with McNemar's exact test")
    p.set_defaults(func=run_stats)

    p = sub.add_parser("recertify", help="re-run a sample of a dataset's trials with this code; "
                                         "if all are identical, the manifest names this code")
    p.add_argument("dataset", help="dataset folder")
    p.add_argument("--sample", type=int, default=36, help="trials to re-run (spread over kinds, "
                                                          "topologies and outcomes)")
    p.add_argument("--workers", type=int, default=1, help="local worker processes")
    p.add_argument("--reference-code", default=None, metavar="DIR",
                   help="a source tree of the code the manifest names (e.g. a git worktree): mismatched "
                        "trials are re-run with it here, and a difference it reproduces is the machine's")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_recertify)

    register_model_commands(sub)

def _fmt(value, spec=".3f") -> str:
    return "-" if value is None else format(value, spec)


def _print_table(rows: list[dict], title: str, extra: tuple[tuple[str, str], ...] = ()) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    table.add_column("network", no_wrap=True, min_width=21)
    for column in ("n", "pos", "AUC", "Brier", "ECE", "ECE floor", "acc") + tuple(name for name, _ in extra):
        table.add_column(column, justify="right", no_wrap=True)
    for row in rows:
        table.add_row(f"{row['topology']}/{row['kind']}", str(row["n"]), str(row["positives"]), _fmt(row["auc"]),
                      _fmt(row["brier"]), _fmt(row["ece"]), _fmt(row.get("ece_floor")), _fmt(row["accuracy"]),
                      *(str(row.get(key, "-")) for _, key in extra))
    console = Console()
    # Piped output (a log file) gets the table's natural width instead of 80 columns.
    Console(width=max(console.width, 120) if not console.is_terminal else None).print(table)


def _figures(entries: list[dict], out: Path, what: str) -> list[str]:
    from qz_drake.capability.plots import plot_confusion, plot_reliability

    named = [dict(e, name=f"{e['topology']}/{e['kind']}") for e in entries if e.get("n")]
    return [str(plot_reliability(named, out / "reliability.png", title=f"Reliability, {what}")),
            str(plot_confusion(named, out / "confusion.png", title=f"Confusion at 0.5, {what}"))]


def run_train(args) -> int:
    if args.learner == "boosted":
        return run_train_boosted(args)
    for name in ("members", "max_iter", "plan_dataset"):
        if getattr(args, name) is not None:
            raise bad_value(f"--{name.replace('_', '-')}", getattr(args, name),
                            "only the boosted learner takes it (--learner boosted)")
    from qz_drake.capability import model_commands, training

    # Looked up in their modules when the command runs (the tests replace them there).
    arrays, manifest = model_commands.load_dataset(args.dataset)
    config = training.TrainingConfig(seed=args.seed)
    if args.max_epochs is not None:
        config.max_epochs = args.max_epochs
    if args.network:
        config.networks = list(args.network)
    result, resumed = model_commands.train_resumably(arrays, manifest, config, args.out, restart=args.restart,
                                      progress=not args.json)
    out = Path(args.out)
    if manifest.get("sources"):  # learned from several datasets: the card names each
        from qz_drake.capability.model_base import MODEL_CARD

        card = json.loads((out / MODEL_CARD).read_text())
        card["sources"] = manifest["sources"]
        (out / MODEL_CARD).write_text(json.dumps(card, indent=2))
    rows = []
    for (topology, kind), network in sorted(result.networks.items(), key=lambda item: training.ALL_NETWORKS.index(item[0])):
        card = network.card
        logistic, boosting = card["baselines"]["logistic"], card["baselines"]["gradient_boosting"]
        rows.append({"topology": topology, "kind": kind, **{k: card["test"][k] for k in SUMMARY_KEYS[2:]},
                     "loss": card.get("run", card["loss"]), "logistic_auc": logistic["auc"], "logistic_brier": logistic["brier"],
                     "boosting_auc": boosting["auc"], "boosting_brier": boosting["brier"],
                     "base_rate_brier": card["baselines"]["base_rate"]["brier"],
                     "beats_baselines": card["beats_baselines"]})
    figures = _figures([dict(r, **result.networks[(r["topology"], r["kind"])].card["test"]) for r in rows],
                       out, "test scenes")
    summary = {"model": str(out), "fingerprint": result.fingerprint, "networks": rows, "missing": result.missing,
               "split_scenes": {k: len(v) for k, v in result.split.items()}, "figures": figures,
               "resumed": [training.network_name(*key) for key in resumed]}
    (out / "report.json").write_text(json.dumps(summary, indent=2))
    if args.json:
        print(json.dumps(summary))
    else:
        for row in rows:
            row["lr_auc"], row["lr_brier"] = _fmt(row["logistic_auc"]), _fmt(row["logistic_brier"])
            row["gb_auc"], row["gb_brier"] = _fmt(row["boosting_auc"]), _fmt(row["boosting_brier"])
            row["rate_brier"] = _fmt(row["base_rate_brier"])
        _print_table(rows, f"Test scenes ({len(result.split['test'])}), model {out}",
                     extra=(("loss", "loss"), ("LR AUC", "lr_auc"), ("LR Brier", "lr_brier"), ("GB AUC", "gb_auc"),
                            ("GB Brier", "gb_brier"), ("rate Brier", "rate_brier"), ("beats", "beats_baselines")))
        print("LR / GB: logistic regression / gradient boosting on patch features; rate: the training base rate; "
              "beats: higher AUC and lower Brier than LR and GB, lower Brier than the rate")
        not_requested = [n for n, why in result.missing.items() if why.startswith("not requested")]
        for name, why in result.missing.items():
            if name not in not_requested:
                print(f"no network {name}: {why}")
        if not_requested:
            print(f"not requested: {', '.join(not_requested)}")
        if resumed:
            print(f"resumed: {', '.join(summary['resumed'])} came from the interrupted training")
        print("figures: " + ", ".join(figures))
    return 0


def run_train_boosted(args) -> int:
    for name in ("max_epochs", "network"):
        if getattr(args, name):
            raise bad_value(f"--{name.replace('_', '-')}", getattr(args, name),
                            "the boosted learner trains one ensemble for every network, without epochs")
    for name, most in (("members", MAX_MEMBERS), ("max_iter", MAX_BOOSTING_ITERATIONS)):
        if getattr(args, name) is not None and not 1 <= getattr(args, name) <= most:
            raise bad_value(f"--{name.replace('_', '-')}", getattr(args, name), f"must be a whole number in [1, {most}]")
    from qz_drake.capability import model_commands
    from qz_drake.capability.boosted import OUTCOMES, BoostedConfig, save_boosted, train_boosted

    arrays, manifest = model_commands.load_dataset(args.dataset)
    plan_arrays = plan_source = None
    if args.plan_dataset is not None:
        from qz_drake.capability.dataset import load_plan_arrays

        plan_arrays, plan_manifest = load_plan_arrays(args.plan_dataset)
        # One BLC-robot system labels both: the chains' plans must be the executed records' BLC's.
        theirs, ours = plan_manifest.get("fingerprints", {}), manifest.get("fingerprints", {})
        differ = [k for k in ("robot", "blc") if theirs.get(k) != ours.get(k)]
        if differ:
            raise bad_value("--plan-dataset", args.plan_dataset,
                            f"its {' and '.join(differ)} fingerprint is not --dataset's: labelled by another BLC-robot "
                            "system (recertify it, or collect it again with this code)")
        plan_source = {"dataset": str(args.plan_dataset), "fingerprint": plan_manifest.get("fingerprint"),
                       "records": int(len(plan_arrays["kind"]))}
    config = BoostedConfig(seed=args.seed)
    if args.members is not None:
        config.members = args.members
    if args.max_iter is not None:
        config.max_iter = args.max_iter
    result = train_boosted(arrays, fingerprint=manifest.get("fingerprint"), fingerprints=manifest.get("fingerprints"),
                           config=config, progress=not args.json, plan_arrays=plan_arrays, plan_source=plan_source)
    if manifest.get("sources"):  # learned from several datasets: the card names each
        result.card["sources"] = manifest["sources"]
    out = save_boosted(result, args.out)
    test = result.card["test"]
    rows = [{"network": name, "n": scores["n"], **{o: scores["counts"][o] for o in OUTCOMES},
             **{f"{o}_auc": scores[o]["auc"] for o in OUTCOMES}, "brier": scores["model"]["brier"],
             "base_rate_brier": scores["base_rate"]["brier"]}
            for name, scores in [("all", test["all"])] + sorted(test["networks"].items())]
    summary = {"model": str(out), "learner": "boosted", "fingerprint": result.card["fingerprint"],
               "members": result.card["members"], "split_scenes": {k: len(v) for k, v in result.card["split"].items()},
               "test": rows}
    if "test_plan" in result.card:
        summary["plan_learner"] = result.card["plan_learner"]
        summary["test_plan"] = {k: v for k, v in result.card["test_plan"].items()
                                if k != "executed_outcome_learners_alone"}
    (out / "report.json").write_text(json.dumps(summary, indent=2))
    if args.json:
        print(json.dumps(summary))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"Test scenes ({summary['split_scenes']['test']}), boosted model {out}")
    for column in ("network", "n", "walked", "no plan", "failed", "AUC walked", "AUC no plan", "AUC failed",
                   "Brier", "rate Brier"):
        table.add_column(column, justify="left" if column == "network" else "right", no_wrap=True)
    for r in rows:
        table.add_row(r["network"], str(r["n"]), *(str(r[o]) for o in OUTCOMES),
                      *(_fmt(r[f"{o}_auc"]) for o in OUTCOMES), _fmt(r["brier"]), _fmt(r["base_rate_brier"]))
    console = Console()
    Console(width=max(console.width, 120) if not console.is_terminal else None).print(table)
    print("Brier: the three outcomes' (multi-class) Brier score; rate: the training outcome frequencies as a "
          f"constant; learners: {', '.join(str(m['iterations']) for m in result.card['members'])} iterations")
    if "test_plan" in summary:
        scores = summary["test_plan"]
        both = [scores[k].get("no_plan", {}) for k in ("with_plan_learners", "outcome_learners_alone")]
        print(f"No plan on the plan chains' test scenes ({scores['with_plan_learners'].get('n', 0)} missions): AUC "
              f"{_fmt(both[0].get('auc'))} with the plan learners, {_fmt(both[1].get('auc'))} without; Brier "
              f"{_fmt(both[0].get('brier'))} / {_fmt(both[1].get('brier'))}; plan learners: "
              f"{', '.join(str(m['iterations']) for m in summary['plan_learner']['members'])} iterations")
    return 0


def run_evaluate(args) -> int:
    from qz_drake.capability import model_commands
    from qz_drake.capability.evaluation import evaluate_model
    from qz_drake.capability.model import CapabilityModel

    model = CapabilityModel.load(args.model)
    arrays, manifest = model_commands.load_dataset(args.dataset)
    results = evaluate_model(model, arrays, manifest)
    summary = {"model": str(args.model or "shipped"), "dataset": str(args.dataset),
               "networks": [{k: r.get(k) for k in SUMMARY_KEYS} | ({"missing": True} if r.get("missing") else {})
                            for r in results]}
    if args.out:
        out = Path(args.out)
        summary["figures"] = _figures(results, out, f"dataset {args.dataset}")
        (out / "evaluation.json").write_text(json.dumps({"networks": results}, indent=2))
    if args.json:
        print(json.dumps(summary))
    else:
        _print_table(summary["networks"], f"Model on {args.dataset}")
    return 0


def run_map(args) -> int:
    if args.topology not in topology_names():
        raise bad_value("--topology", args.topology, f"expected one of {', '.join(topology_names())}")
    import numpy as np

    from qz_drake.capability import model_commands
    from qz_drake.capability.model import CapabilityModel
    from qz_drake.capability.plots import plot_capability_map

    model = CapabilityModel.load(args.model, device=args.device)
    heightmap = model_commands.load_terrain(args.terrain, args.terrain_param, args.seed)
    capability = model.map_success(heightmap, [args.topology])
    png = plot_capability_map(heightmap, capability, args.out, topology=args.topology,
                              title=f"P(forward success), {args.topology}, {args.terrain}")
    forward = capability.forward[0]
    print(json.dumps({"png": str(png), "topology": args.topology, "cells": [len(capability.ys), len(capability.xs)],
                      "mean_forward_success": float(np.mean(forward)),
                      "min_forward_success": float(np.min(forward))}))
    return 0


def register_model_commands(subparsers) -> None:
    """Adds ``train``, ``evaluate`` and ``map`` to the ``qz capability`` subparsers."""
    p = subparsers.add_parser("train", help="train the capability networks on a trial dataset")
    p.add_argument("--dataset", required=True, action="append",
                   help="trial dataset folder; repeat it to learn from several of one BLC-robot system together "
                        "(e.g. an episode collection and the episodes of the planners' routes, collect-routes)")
    p.add_argument("--out", required=True, help="model folder to write")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--seed", type=int, default=0, help="split, initialisation and batch order")
    p.add_argument("--max-epochs", type=int, default=None, help="cap on epochs per run")
    p.add_argument("--network", action="append", metavar="TOPOLOGY/KIND",
                   help="train only this network (repeatable); default all with data")
    p.add_argument("--restart", action="store_true",
                   help="discard the networks an interrupted training left in --out and train all again "
                        "(without it, the same command goes on where the training stopped)")
    p.add_argument("--learner", default="cnn", choices=LEARNERS,
                   help="cnn: the paper's 18 networks; boosted: one gradient-boosted ensemble for every "
                        "topology and kind (qz_drake.capability.boosted; three outcomes)")
    p.add_argument("--members", type=int, default=None,
                   help="learners in the boosted ensemble (default 5); only with --learner boosted")
    p.add_argument("--max-iter", type=int, default=None,
                   help="most boosting iterations of each learner (default 400; each stops sooner when its "
                        "validation loss stops improving); only with --learner boosted")
    p.add_argument("--plan-dataset", default=None,
                   help="a plan chain dataset (collect --protocol plans) of the same BLC-robot system: a plan "
                        "learner beside each boosted learner learns whether the BLC plans from its missions too; "
                        "only with --learner boosted")
    p.set_defaults(func=run_train)

    p = subparsers.add_parser("evaluate", help="score a capability model on a trial dataset")
    p.add_argument("--model", default=None, help="model folder (default: the shipped model)")
    p.add_argument("--dataset", required=True, help="trial dataset folder")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--out", default=None, help="also write reliability / confusion PNGs here")
    p.set_defaults(func=run_evaluate)

    p = subparsers.add_parser("map", help="draw the predicted success of moving forward over a terrain")
    p.add_argument("--model", default=None, help="model folder (default: the shipped model)")
    p.add_argument("--device", default=None,
                   help="where the networks run: cpu, cuda, cuda:N or auto (default: QZ_TORCH_DEVICE, else cpu)")
    p.add_argument("--terrain", required=True,
                   help=LazyText(lambda: f"a .npz / .yaml heightmap, a picture (its scale as --terrain-param "
                                         f"resolution=M max_height=M [min_height=M]), or a terrain generator, "
                                         f"{one_of(terrain_names())} (parameters: qz terrain --help)"))
    p.add_argument("--terrain-param", action="append", metavar="KEY=VALUE", help="generator parameter, seed included")
    p.add_argument("--seed", type=int, default=0, help="terrain generator seed")
    p.add_argument("--topology", default="nominal", help=LazyText(lambda: f"body topology, {one_of(topology_names())}"))
    p.add_argument("--out", required=True, help="PNG file to write")
    p.set_defaults(func=run_map, out_kind="file")
