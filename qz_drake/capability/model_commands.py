"""``qz capability train``, ``qz capability evaluate`` and ``qz capability map`` (issue #13).

``qz capability train --dataset DIR --out DIR [--json] [--restart]`` trains the 18 networks on
a trial dataset (split by scene), writes the model directory (safetensors + JSON cards) with
``reliability.png`` and ``confusion.png`` of the test scenes, and prints the metrics table
(or one JSON line). Each network is kept as soon as it is trained: after Ctrl-C the same
command trains only the missing ones.

``qz capability evaluate [--model DIR] --dataset DIR [--json] [--out DIR]`` scores a model on
every trial of a dataset whose fingerprints are the model's; the JSON has one entry per
network with topology, kind, n, positives, auc, brier, ece, ece_floor (the ECE a calibrated
model would score on so few trials), accuracy.

``qz capability map --model DIR --terrain NAME|FILE --topology T --out FILE.png`` draws the
predicted success of moving forward from every 1 m cell and heading over the heightmap.

The lead's qz_drake/capability/commands.py registers the ``capability`` group and calls
:func:`register_model_commands` with its subparsers.
"""

from __future__ import annotations

import json
from pathlib import Path

from qz_drake.errors import ConfigError, bad_value

SUMMARY_KEYS = ("topology", "kind", "n", "positives", "auc", "brier", "ece", "ece_floor", "accuracy")


def load_dataset(path) -> tuple[dict, dict]:
    """(arrays, manifest) of a trial dataset, through qz_drake.capability.dataset."""
    try:
        from qz_drake.capability.dataset import load_training_arrays
    except ModuleNotFoundError as e:
        if e.name != "qz_drake.capability.dataset":
            raise
        raise ConfigError(f"--dataset = {str(path)!r}: this checkout has no trial dataset reader "
                          "(qz_drake.capability.dataset)") from None
    return load_training_arrays(path)


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


def train_resumably(arrays: dict, manifest: dict, config, out, *, restart: bool = False, progress: bool = False):
    """Trains the networks into the model folder ``out`` so that an interruption keeps what
    finished: each network is saved in ``out/unfinished_training/`` as soon as it is trained,
    and the same training run again (same dataset, settings and code) trains only the ones
    missing there; the folder becomes the model (save_model) when all are done. ``restart``
    discards an unfinished training there first. Returns (TrainingResult, networks resumed)."""
    import dataclasses
    import shutil

    from qz_drake.capability.model import UNFINISHED_DIR, save_model, save_network, unfinished_networks
    from qz_drake.capability.training import train_networks, training_identity

    fingerprint, fingerprints = manifest.get("fingerprint"), manifest.get("fingerprints")
    config.check()
    unfinished = Path(out) / UNFINISHED_DIR
    if restart and unfinished.is_dir():
        shutil.rmtree(unfinished)
    identity = training_identity(arrays, fingerprint=fingerprint, fingerprints=fingerprints, config=config)
    finished = unfinished_networks(unfinished, identity) if unfinished.is_dir() else {}
    settings = dataclasses.asdict(config)

    def keep(network):
        save_network(unfinished, network, fingerprint=fingerprint, fingerprints=dict(fingerprints or {}),
                     config=settings, identity=identity)

    try:
        result = train_networks(arrays, fingerprint=fingerprint, fingerprints=fingerprints, config=config,
                                progress=progress, finished=finished, on_network=keep)
    except KeyboardInterrupt:
        import sys

        done = len(list(unfinished.glob("*.json"))) if unfinished.is_dir() else 0
        print(f"qz capability train: {done} trained networks kept in {unfinished}; the same command trains "
              "the rest", file=sys.stderr)
        raise
    save_model(result, out)
    shutil.rmtree(unfinished, ignore_errors=True)
    return result, sorted(finished)


def run_train(args) -> int:
    from qz_drake.capability.training import ALL_NETWORKS, TrainingConfig, network_name

    arrays, manifest = load_dataset(args.dataset)
    config = TrainingConfig(seed=args.seed)
    if args.max_epochs is not None:
        config.max_epochs = args.max_epochs
    if args.network:
        config.networks = list(args.network)
    result, resumed = train_resumably(arrays, manifest, config, args.out, restart=args.restart,
                                      progress=not args.json)
    out = Path(args.out)
    rows = []
    for (topology, kind), network in sorted(result.networks.items(), key=lambda item: ALL_NETWORKS.index(item[0])):
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
               "resumed": [network_name(*key) for key in resumed]}
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


def run_evaluate(args) -> int:
    from qz_drake.capability.evaluation import evaluate_model
    from qz_drake.capability.model import CapabilityModel

    model = CapabilityModel.load(args.model)
    arrays, manifest = load_dataset(args.dataset)
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


def load_terrain(name_or_file: str, params: list[str] | None, seed: int):
    """A HeightMap from a file (.npz or map-server .yaml) or a generator name with KEY=VALUE
    parameters."""
    from qz_drake.cli import parse_key_values
    from qz_drake.config import TerrainConfig
    from qz_drake.station import make_heightmap
    from qz_drake.terrain import HeightMap

    path = Path(name_or_file)
    if path.suffix in (".npz", ".yaml", ".yml"):
        if params:
            raise bad_value("--terrain-param", params, "parameters apply to a generated terrain, not a file")
        return HeightMap.load(path)
    return make_heightmap(TerrainConfig(kind=name_or_file, params=parse_key_values(params, "--terrain-param")),
                          seed=seed)


def run_map(args) -> int:
    import numpy as np

    from qz_drake.capability.model import CapabilityModel
    from qz_drake.capability.plots import plot_capability_map
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    if args.topology not in TOPOLOGY_NAMES:
        raise bad_value("--topology", args.topology, f"expected one of {', '.join(TOPOLOGY_NAMES)}")
    model = CapabilityModel.load(args.model)
    heightmap = load_terrain(args.terrain, args.terrain_param, args.seed)
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
    p.add_argument("--dataset", required=True, help="trial dataset folder")
    p.add_argument("--out", required=True, help="model folder to write")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--seed", type=int, default=0, help="split, initialisation and batch order")
    p.add_argument("--max-epochs", type=int, default=None, help="cap on epochs per run")
    p.add_argument("--network", action="append", metavar="TOPOLOGY/KIND",
                   help="train only this network (repeatable); default all with data")
    p.add_argument("--restart", action="store_true",
                   help="discard the networks an interrupted training left in --out and train all again "
                        "(without it, the same command goes on where the training stopped)")
    p.set_defaults(func=run_train)

    p = subparsers.add_parser("evaluate", help="score a capability model on a trial dataset")
    p.add_argument("--model", default=None, help="model folder (default: the shipped model)")
    p.add_argument("--dataset", required=True, help="trial dataset folder")
    p.add_argument("--json", action="store_true", help="print one JSON line")
    p.add_argument("--out", default=None, help="also write reliability / confusion PNGs here")
    p.set_defaults(func=run_evaluate)

    from qz_drake.cli import one_of, terrain_names
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    p = subparsers.add_parser("map", help="draw the predicted success of moving forward over a terrain")
    p.add_argument("--model", default=None, help="model folder (default: the shipped model)")
    p.add_argument("--terrain", required=True,
                   help=f"a .npz / .yaml heightmap, or a terrain generator, {one_of(terrain_names())} "
                        f"(parameters: qz terrain --help)")
    p.add_argument("--terrain-param", action="append", metavar="KEY=VALUE", help="generator parameter, seed included")
    p.add_argument("--seed", type=int, default=0, help="terrain generator seed")
    p.add_argument("--topology", default="nominal", help=f"body topology, {one_of(TOPOLOGY_NAMES)}")
    p.add_argument("--out", required=True, help="PNG file to write")
    p.set_defaults(func=run_map, out_kind="file")
