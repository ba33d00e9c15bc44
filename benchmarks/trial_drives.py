"""Stored capability episodes re-run with the joints driven another way (TrialConfig's
``control_mode`` and ``time_step``): each mission's outcome against the stored label, and the
time side by side with the dataset's own settings.

    python benchmarks/trial_drives.py data/capability_episodes EPISODES OUT.jsonl \\
        [--control-mode position] [--time-step 0.004] [--setup MODULE:FUNCTION] [--workers 2]

EPISODES episodes are drawn as a recertification draws them (spread over every status, kind,
topology, outcome and scene kind: failures are over-represented against the dataset), or with
``--uniform`` uniformly from the dataset's episodes (how many of its labels the setting would
move), from a fixed key; each is run twice in worker processes, with the dataset's settings
("stored": they reproduce the stored records, the dataset being certified for this code) and with the
variant, the two jobs of an episode side by side. ``--setup MODULE:FUNCTION`` (a module of
benchmarks/) is called in the worker before each of the variant's episodes and the function
it returns after it (a solver variant such as ``blc_row_screening:use``; with ``--control-mode
torque --time-step 0.002`` it is then the only difference). Writes one JSON line per (episode, setting)
with its missions' outcomes (walked / no_plan / failed), reasons, final position errors and
the episode's wall time; prints the missions whose outcome differs from the stored one and the
time ratio.
"""

import argparse
import dataclasses
import json
import statistics
import sys
import time
from multiprocessing import get_context



def _run(job):
    settings, spec, setup = job
    from qz_drake.capability.collect import execute_episode
    from qz_drake.capability.trials import TrialConfig

    # The setup, and its undo after the episode: a worker also runs the other setting's jobs.
    undo = getattr(__import__(setup.split(":")[0]), setup.split(":")[1])() if setup else None
    try:
        clock = time.perf_counter()
        records = execute_episode(spec, TrialConfig(**settings))
        wall = time.perf_counter() - clock
    finally:
        if undo is not None:
            undo()
    missions = []
    for r in records:
        missions.append({"status": r.get("status"),
                         "outcome": _outcome(r.get("status"), bool(r.get("success")), bool(r.get("blc_success"))),
                         "reason": r.get("reason"), "final_xy_error_m": _num(r.get("final_xy_error_m")),
                         "max_joint_error_deg": _num(r.get("max_joint_error_deg")),
                         "blc_iterations": int(r.get("blc_iterations") or 0)})
    return settings, spec.index, wall, missions, setup


def _outcome(status: str, success: bool, planned: bool) -> str:
    """A mission's label: its outcome (training.OUTCOMES) when executed, else its status."""
    from qz_drake.capability.training import OUTCOMES, outcome_classes

    return OUTCOMES[int(outcome_classes(success, planned))] if status == "executed" else status


def _num(x):
    return None if x is None else float(x)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("episodes", type=int)
    parser.add_argument("out")
    parser.add_argument("--control-mode", default="position")
    parser.add_argument("--time-step", type=float, default=0.004)
    parser.add_argument("--setup", default=None, help="MODULE:FUNCTION of benchmarks/ around the variant's episodes")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--uniform", action="store_true",
                        help="draw the episodes uniformly from the dataset (how many labels a setting moves) instead "
                             "of as a recertification draws them (failures over-represented)")
    parser.add_argument("--summary-only", action="store_true", help="summarise OUT's runs again, run nothing")
    args = parser.parse_args()
    from qz_drake.capability.collect import _episode_sample
    from qz_drake.capability.dataset import load_records, read_manifest
    from qz_drake.capability.trials import TrialConfig

    manifest = read_manifest(args.dataset)
    settings = dict(manifest["settings"])
    if settings.pop("protocol", "moves") != "episodes":
        sys.exit("trial_drives.py: an episode dataset is needed")
    variant = dataclasses.asdict(dataclasses.replace(TrialConfig(**settings), control_mode=args.control_mode,
                                                     time_step=args.time_step))
    arrays, _ = load_records(args.dataset)
    specs, stored = _episode_sample(arrays, args.episodes, "trial_drives", int(manifest["seed"]), uniform=args.uniform)
    labels = {e: [_outcome(str(r["status"][0]), bool(r["success"][0]), bool(r["blc_success"][0])) for r in records]
              for e, records in stored.items()}
    results: dict = {}
    if args.summary_only:  # the runs of an earlier call
        for line in open(args.out):
            d = json.loads(line)
            results[(d["episode"], d["setting"])] = (d["wall_s"], d["missions"])
    else:
        jobs = [(s, spec, setup) for spec in specs for s, setup in ((settings, None), (variant, args.setup))]
        with get_context("spawn").Pool(args.workers, maxtasksperchild=20) as pool, open(args.out, "w") as out:
            for used, index, wall, missions, setup in pool.imap_unordered(_run, jobs):
                name = "stored" if used == settings and setup is None else "variant"
                results[(index, name)] = (wall, missions)
                out.write(json.dumps({"episode": index, "setting": name, "wall_s": wall, "missions": missions,
                                      "stored_outcomes": labels[index]}) + "\n")
                out.flush()
    compared = same = reproduced = 0
    walls = {"stored": [], "variant": []}
    changes = []
    for index in labels:
        for name in walls:
            walls[name].append(results[(index, name)][0])
        now = [m["outcome"] for m in results[(index, "variant")][1]]
        again = [m["outcome"] for m in results[(index, "stored")][1]]
        reproduced += again == labels[index]
        for k, (a, b) in enumerate(zip(labels[index], now)):
            compared += 1
            same += a == b
            if a != b:
                changes.append((index, k, a, b, results[(index, "variant")][1][k]["reason"]))
        if len(now) != len(labels[index]):
            changes.append((index, "missions", len(labels[index]), len(now), ""))
    print(f"{len(labels)} episodes; the stored settings reproduced {reproduced} of them exactly")
    print(f"missions compared (both ran them): {compared}; the same outcome: {same}")
    for c in changes:
        print("  changed:", c)
    ts, tv = sum(walls["stored"]), sum(walls["variant"])
    print(f"wall time: stored settings {ts:.1f} s, variant {tv:.1f} s, ratio {tv / ts:.3f} "
          f"(per episode median {statistics.median(v / s for s, v in zip(walls['stored'], walls['variant'])):.3f})")


if __name__ == "__main__":
    main()
