"""``qz impedance-sweep``, ``qz trot`` and ``qz classify {collect,train,experiment}`` (paper 002).

``qz impedance-sweep [--json] [--out DIR]`` runs Fig. 13's one-leg model at 5, 15 and 25 kN/m
and prints ``{"stiffness_N_per_m": [...], "max_error_m": [...], "oscillates": [...]}``.

``qz trot SCENARIO.yaml [--out DIR]`` trots a scenario's floor at ``controller.speed`` for
``simulation.duration`` (the trot_*.yaml scenarios) and writes ``recording.html`` and
``metrics.json`` to DIR (default out/trot), as ``qz simulate`` does.

``qz classify collect --out DIR`` trots over each material at random speeds (5 kg payload)
and writes ``DIR/dataset.npz``; ``qz classify train --dataset DIR --out DIR [--json]`` trains
the per-leg SVMs, writes ``models.npz``, ``report.json`` and ``confusion.png`` and prints the
tables (or ``{"classes": [...], "per_leg": [{"leg", "accuracy", "confusion", "C", "gamma"},
...]}``); ``qz classify experiment --models FILE --out DIR`` runs Figs. 15-16 (fixed against
adaptive stiffness on foam and concrete) and the mixed floor; ``qz classify stiffness-sweep``
trots each material at fixed stance stiffnesses and reports the vibration of each (the sweep
that chooses the experiment's "simulation presets").
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from qz_drake.cli.arguments import LazyText, one_of
from qz_drake.errors import bad_value


def _positive_list(text: str, field: str) -> list[float]:
    try:
        values = [float(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise bad_value(field, text, "expected comma-separated numbers") from None
    if not values or not all(math.isfinite(v) and v > 0 for v in values):
        raise bad_value(field, text, "expected positive numbers")
    return values


def _materials(text: str, field: str) -> list[str]:
    """Comma-separated ground material names, each checked (an unknown one is named)."""
    from qz_drake.terrain import get_material

    names = [m.strip() for m in str(text).split(",") if m.strip()]
    if not names:
        raise bad_value(field, text, "give at least one ground material")
    for name in names:
        get_material(name)
    return names


def run_impedance_sweep(args) -> int:
    from qz_drake.classification.impedance_sweep import ImpedanceSweepConfig, plot_sweep, run_sweep

    config = ImpedanceSweepConfig()
    if args.stiffness is not None:
        config.stiffnesses = _positive_list(args.stiffness, "--stiffness")
    if args.torque_lag is not None:
        if not (math.isfinite(args.torque_lag) and args.torque_lag >= 0):
            raise bad_value("--torque-lag", args.torque_lag, "must be a non-negative number of seconds")
        config.torque_lag = args.torque_lag
    result = run_sweep(config)
    summary = {k: result[k] for k in ("stiffness_N_per_m", "max_error_m", "oscillates")}
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        summary_file = dict(summary, oscillation_amplitude_m=result["oscillation_amplitude_m"],
                            config=result["config"], png=plot_sweep(result, out / "impedance_sweep.png"))
        (out / "impedance_sweep.json").write_text(json.dumps(summary_file, indent=2))
    if args.json:
        print(json.dumps(summary))
    else:
        for k, e, o in zip(summary["stiffness_N_per_m"], summary["max_error_m"], summary["oscillates"]):
            print(f"K = {k / 1e3:5.1f} kN/m   max error {e:.4f} m   {'oscillates' if o else ''}")
    return 0


def run_trot(args) -> int:
    from qz_drake.classification.runs import simulate_trot
    from qz_drake.cli.arguments import output_folder, positive_seconds, prepare_scenario
    from qz_drake.config import load_scenario
    from qz_drake.state_layout import BASE_POS
    from qz_drake.viz.recording import recording_meshcat, save_recording

    scenario = load_scenario(args.scenario)
    positive_seconds(args.duration, "--duration")
    output_folder(args.out, create=False)
    prepare_scenario(scenario)
    out = output_folder(args.out)
    duration = scenario.simulation.duration if args.duration is None else args.duration
    speed = scenario.controller.speed if args.speed is None else args.speed
    meshcat = recording_meshcat()
    meshcat.StartRecording()
    run = simulate_trot(scenario, duration=duration, speed=speed, meshcat=meshcat)
    meshcat.StopRecording()
    recording = save_recording(meshcat, out / "recording.html", follow_robot=True)
    T = 1.0 if run.times[-1] > 2.0 else run.times[-1] / 2
    late = run.times >= run.times[-1] - T
    metrics = {"scenario": scenario.name, "fell": run.fell, "success": not run.fell,
               "distance_m": float(run.states[-1, BASE_POS][0] - run.states[0, BASE_POS][0]),
               "final_speed_m_per_s": float((run.states[late][-1, BASE_POS][0] - run.states[late][0, BASE_POS][0]) / T),
               "stances": int(len(run.stance_leg)), "wall_time_s": run.wall_time_s,
               "sim_time_s": float(run.times[-1]), "speed_m_per_s": float(speed)}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    metrics["files"] = {"recording": str(recording), "metrics": str(out / "metrics.json")}
    print(json.dumps(metrics))
    return 0 if metrics["success"] else 1


def _collect_config(args):
    from qz_drake.classification.dataset import CollectConfig

    config = CollectConfig(seed=args.seed)
    if args.materials:
        config.materials = _materials(args.materials, "--materials")
    if args.stances is not None:
        config.stances_per_class = args.stances
    if args.run_duration is not None:
        from qz_drake.cli.arguments import positive_seconds

        config.run_duration = positive_seconds(args.run_duration, "--run-duration")
    if args.mixed_runs is not None:
        config.mixed_runs = args.mixed_runs
    return config.check()


def run_collect(args) -> int:
    from qz_drake.classification.dataset import collect_dataset, summary

    config = _collect_config(args)
    dataset = collect_dataset(config, args.out, progress=not args.json, workers=args.workers)
    result = dict(summary(dataset), dataset=str(Path(args.out) / "dataset.npz"))
    print(json.dumps(result) if args.json else json.dumps(result, indent=2))
    return 0


def run_train(args) -> int:
    from qz_drake.classification.dataset import StanceDataset
    from qz_drake.classification.plots import plot_confusion_matrices
    from qz_drake.classification.svm import format_tables, repeated_holdout, save_models, train_all_legs

    if args.repeats < 1:
        raise bad_value("--repeats", args.repeats, "must be a positive integer")
    dataset = StanceDataset.load(args.dataset)
    models, report = train_all_legs(dataset, seed=args.seed)
    if args.repeats > 1:
        report["repeated_holdout"] = repeated_holdout(dataset, repeats=args.repeats, seed=args.seed,
                                                      first_report=report)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    save_models(models, out / "models.npz", metadata={"classes": report["classes"], "seed": args.seed,
                                                      "dataset": str(args.dataset)})
    (out / "report.json").write_text(json.dumps(report, indent=2))
    plot_confusion_matrices(report, out / "confusion.png")
    if args.json:
        # accuracy: the held-out 20 % of the one-material stances (the paper's protocol);
        # mixed: the held-out 20 % of the mixed-floor stances, where the dataset has them.
        keys = ("leg", "accuracy", "confusion", "precision", "recall", "C", "gamma", "mixed")
        summary = {"classes": report["classes"],
                   "per_leg": [{k: leg[k] for k in keys if k in leg} for leg in report["per_leg"]],
                   "mean_accuracy": report["mean_accuracy"]}
        if "repeated_holdout" in report:
            summary["repeated_holdout"] = {k: v for k, v in report["repeated_holdout"].items() if k != "accuracy"}
        print(json.dumps(summary))
    else:
        print(format_tables(report))
        print(f"mean held-out accuracy over the legs: {100 * report['mean_accuracy']:.2f} %")
        if "repeated_holdout" in report:
            rep = report["repeated_holdout"]
            per_leg = ", ".join(f"{leg} {100 * a:.2f}" for leg, a in rep["per_leg_mean"].items())
            print(f"over {rep['repeats']} random splits: mean {100 * rep['mean_accuracy']:.2f} % "
                  f"(std of split means {100 * rep['std_of_split_means']:.2f} %); per leg {per_leg} %")
        print(f"models: {out / 'models.npz'}")
    return 0


def run_experiment(args) -> int:
    from qz_drake.classification.experiments import ExperimentConfig, run_experiments

    config = ExperimentConfig.quick() if args.quick else ExperimentConfig()
    result = run_experiments(args.models, args.out, config, progress=not args.json)
    print(json.dumps(result) if args.json else json.dumps(result, indent=2))
    return 0


def run_stiffness_sweep(args) -> int:
    from qz_drake.classification.experiments import ExperimentConfig, preset_sweep

    materials = _materials(args.materials, "--materials")
    if not (math.isfinite(args.speed) and 0.0 <= args.speed <= 1.0):
        raise bad_value("--speed", args.speed, "must be within [0, 1] m/s")
    config = ExperimentConfig(preset_candidates=_positive_list(args.stiffness, "--stiffness"))
    result = preset_sweep(materials, config, speed=args.speed)
    if args.json:
        print(json.dumps(result))
    else:
        for material, rows in result["table"].items():
            for row in rows:
                a, h = row["vertical_acceleration_m_per_s2"], row["height_m"]
                print(f"{material:9s} K = {row['stiffness_N_per_m'] / 1e3:5.1f} kN/m   acceleration IQR "
                      f"{a['iqr']:.3f} m/s^2 (5-95 % {a['p5_p95']:.3f})   height IQR {1e3 * h['iqr']:.1f} mm"
                      + ("   fell" if row["fell"] else ""))
        print("narrowest acceleration box:", json.dumps(result["presets"]))
    return 0


def register(subparsers) -> None:
    """Adds ``impedance-sweep``, ``trot`` and ``classify`` to the ``qz`` command."""
    def materials(default: str) -> LazyText:
        # The ground materials, looked up when the help page is shown.
        def text() -> str:
            from qz_drake.terrain import MATERIALS

            return f"comma-separated materials, each {one_of(MATERIALS)} (default {default})"

        return LazyText(text)

    p = subparsers.add_parser("impedance-sweep", help="leg impedance stiffness sweep (paper 002 Fig. 13)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--out", default=None, help="folder for impedance_sweep.png and .json")
    p.add_argument("--stiffness", default=None, metavar="K1,K2,...", help="leg stiffnesses [N/m]")
    p.add_argument("--torque-lag", type=float, default=None, help="torque-loop lag [s] (default 0.012)")
    p.set_defaults(func=run_impedance_sweep)

    p = subparsers.add_parser("trot", help="trot a scenario's floor (paper 002 tripod trotting)")
    p.add_argument("scenario", help="scenario YAML file (scenarios/trot_*.yaml)")
    p.add_argument("--speed", type=float, default=None, help="forward speed [m/s] (default controller.speed)")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s]")
    p.add_argument("--out", default="out/trot", help="output folder (recording.html, metrics.json)")
    p.set_defaults(func=run_trot)

    classify = subparsers.add_parser("classify", help="terrain classification (paper 002)")
    sub = classify.add_subparsers(dest="classify_command", required=True, parser_class=type(classify))

    p = sub.add_parser("collect", help="trot over each material and write a stance dataset")
    p.add_argument("--out", default="out/classify", help="output folder (dataset.npz, runs/)")
    p.add_argument("--stances", type=int, default=None, help="stances per class and leg (default 200)")
    p.add_argument("--run-duration", type=float, default=None, help="simulated time per run [s] (default 20)")
    p.add_argument("--materials", default=None, help=materials("concrete,wood,foam"))
    p.add_argument("--mixed-runs", type=int, default=None,
                   help="extra runs over floors of random material patches (default 6)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1, help="simulate runs in this many processes (default 1)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_collect)

    p = sub.add_parser("train", help="per-leg RBF SVMs with grid search (Tables 1-2)")
    p.add_argument("--dataset", default="out/classify/dataset.npz", help="dataset.npz or its folder")
    p.add_argument("--out", default="out/classify", help="output folder (models.npz, report.json, confusion.png)")
    p.add_argument("--seed", type=int, default=0, help="seeds the 80/20 split and the CV folds")
    p.add_argument("--repeats", type=int, default=1,
                   help="also report the held-out accuracy over this many random splits (default 1: none)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_train)

    p = sub.add_parser("stiffness-sweep", help="vibration of a trot at fixed stance stiffnesses, per material")
    p.add_argument("--materials", default="foam,concrete", help=materials("foam,concrete"))
    p.add_argument("--stiffness", default="7000,9000,11000", metavar="K1,K2,...",
                   help="stance stiffnesses [N/m] (default the paper's three)")
    p.add_argument("--speed", type=float, default=0.6, help="forward speed [m/s] (default 0.6)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_stiffness_sweep)

    p = sub.add_parser("experiment", help="fixed vs adaptive stiffness (Figs. 15-16) and the mixed floor")
    p.add_argument("--models", default="out/classify/models.npz", help="models.npz from qz classify train")
    p.add_argument("--out", default="out/classify/experiment", help="output folder")
    p.add_argument("--quick", action="store_true", help="short runs (for tests)")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.set_defaults(func=run_experiment)
