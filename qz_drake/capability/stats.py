"""Summaries of a capability dataset (``qz capability stats``): success rates per topology and
kind, the up-stairs comparison of paper 000 with Wilson intervals, and two datasets of the same
trials paired with McNemar's exact test.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import sys

import numpy as np

from qz_drake.errors import bad_value


# Bins of the stair rise [m] for the topology comparison (paper 000: bend-inside legs are
# safer going up stairs; a longer nominal stance is better on higher stairs).
RISE_BINS = ((0.04, 0.10), (0.10, 0.16), (0.16, 0.27))
# A move goes up a flight when its heading is within this of the flight's direction. [deg]
UP_STAIRS_CONE_DEG = 50.0


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a success rate (95 % by default); (0, 1) for n = 0."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return float(max(0.0, centre - half)), float(min(1.0, centre + half))


def _stairs_rise(arrays: dict, row: int, seed: int) -> float:
    """The rise of record ``row``'s stairs scene [m], rebuilt from the record's own recipe
    (difficulty, scene seed): a scene index names another scene once the mix of scene kinds
    changes (the shipped dataset's stairs scenes are mostly other kinds by index today). A
    record without its recipe is looked up by index; NaN where that is no flight of stairs."""
    from qz_drake.capability.scenes import make_scene, scene_for

    if "difficulty" in arrays and "scene_seed" in arrays:
        scene = make_scene("stairs", float(arrays["difficulty"][row]), int(arrays["scene_seed"][row]))
    else:
        scene = scene_for(seed, int(arrays["scene"][row]))
    return float(scene.params.get("rise", np.nan))


def stairs_up_rows(arrays: dict, seed: int) -> list[dict]:
    """Success of forward moves (orthogonal, diagonal) up a flight of stairs, per topology and
    rise bin, with Wilson 95 % intervals: the comparison paper 000 draws between topologies.
    A scene's flight climbs along +x (scenes.stairs_scene); a move goes up it when the scene's
    rise is positive and the heading is within UP_STAIRS_CONE_DEG of +x."""
    executed = (arrays["status"] == "executed") & (arrays["scene_kind"] == "stairs") \
        & np.isin(arrays["kind"], ("orthogonal", "diagonal"))
    rise = np.full(len(executed), np.nan)
    for scene in np.unique(arrays["scene"][executed]):
        in_scene = arrays["scene"] == scene
        rise[in_scene] = _stairs_rise(arrays, int(np.flatnonzero(in_scene & executed)[0]), seed)
    up = executed & (rise > 0) & (np.cos(arrays["heading"]) >= np.cos(np.radians(UP_STAIRS_CONE_DEG)))
    rows = []
    for low, high in RISE_BINS:
        in_bin = up & (rise >= low) & (rise < high)
        for topology in sorted(set(arrays["topology"][in_bin].tolist())):
            sel = in_bin & (arrays["topology"] == topology)
            n, k = int(sel.sum()), int(arrays["success"][sel].sum())
            lo, hi = wilson_interval(k, n)
            rows.append({"rise_m": [low, high], "topology": topology, "executed": n, "successes": k,
                         "success_rate": k / n, "ci95": [lo, hi]})
    return rows


# Rises from which paper 000's claims are about higher stairs (the upper two RISE_BINS). [m]
HIGH_STAIRS_RISE = 0.10


def stairs_up_comparisons(rows: list[dict], reference: str = "nominal") -> list[dict]:
    """Each topology against ``reference`` going up stairs of rise >= HIGH_STAIRS_RISE (the
    stairs_up rows pooled): successes / moves of both and the two-sided Fisher exact p-value of
    the difference (scipy.stats.fisher_exact), the test paper 000's topology claims need."""
    from scipy.stats import fisher_exact

    pooled: dict[str, list[int]] = {}
    for row in rows:
        if row["rise_m"][0] >= HIGH_STAIRS_RISE - 1e-9:
            k, n = pooled.setdefault(row["topology"], [0, 0]), row
            k[0] += n["successes"]
            k[1] += n["executed"]
    if reference not in pooled:
        return []
    ref_k, ref_n = pooled[reference]
    out = []
    for topology, (k, n) in sorted(pooled.items()):
        if topology == reference or n == 0 or ref_n == 0:
            continue
        _, p = fisher_exact([[k, n - k], [ref_k, ref_n - ref_k]])
        out.append({"topology": topology, "reference": reference, "min_rise_m": HIGH_STAIRS_RISE,
                    "successes": k, "executed": n, "reference_successes": ref_k, "reference_executed": ref_n,
                    "p_value": float(p)})
    return out


def outcome_counts(arrays: dict, mask) -> dict:
    """Of the executed records in ``mask``: walked, no plan (the BLC found none; the robot
    stood) and executed and failed."""
    ex = np.asarray(mask) & (np.asarray(arrays["status"]) == "executed")
    walked = ex & np.asarray(arrays["success"], dtype=bool)
    planned = ex & np.asarray(arrays["blc_success"], dtype=bool)
    return {"executed": int(ex.sum()), "walked": int(walked.sum()), "no_plan": int((ex & ~planned).sum()),
            "failed": int((planned & ~walked).sum())}


def topology_rows(arrays: dict, reference: str = "nominal") -> list[dict]:
    """Where the topologies differ (issue 37): per scene kind and action (moves, turns), each
    topology's three outcomes and the two-sided Fisher exact p-value of its walked share
    against ``reference``'s on the same scene kind and action (topology switches excluded:
    :func:`switch_rows`)."""
    from scipy.stats import fisher_exact

    kind = np.asarray(arrays["kind"]).astype(str)
    actions = {"moves": np.isin(kind, ("orthogonal", "diagonal")), "turns": kind == "turn"}
    scene_kind = np.asarray(arrays["scene_kind"]).astype(str)
    topology = np.asarray(arrays["topology"]).astype(str)
    rows = []
    for sk in sorted(set(scene_kind.tolist())):
        for action, in_action in actions.items():
            base = (scene_kind == sk) & in_action
            ref = outcome_counts(arrays, base & (topology == reference))
            for t in sorted(set(topology[base].tolist())):
                c = outcome_counts(arrays, base & (topology == t))
                if not c["executed"]:
                    continue
                p = None
                if t != reference and ref["executed"]:
                    _, p = fisher_exact([[c["walked"], c["executed"] - c["walked"]],
                                         [ref["walked"], ref["executed"] - ref["walked"]]])
                rows.append({"scene_kind": sk, "action": action, "topology": t, **c,
                             "walked_rate": c["walked"] / c["executed"],
                             "p_against_reference": None if p is None else float(p), "reference": reference})
    return rows


def switch_rows(arrays: dict) -> list[dict]:
    """Topology switches of an episode dataset (kind "switch") per scene kind and the topology
    switched to: executed, walked (the switch done and the robot standing in the new topology
    where it stood), refused before it started (no plan) and failed."""
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    kind = np.asarray(arrays["kind"]).astype(str)
    scene_kind = np.asarray(arrays["scene_kind"]).astype(str)
    topology = np.asarray(arrays["topology"]).astype(str)
    rows = []
    for sk in sorted(set(scene_kind[kind == "switch"].tolist())):
        for t in TOPOLOGY_NAMES:
            c = outcome_counts(arrays, (kind == "switch") & (scene_kind == sk) & (topology == t))
            if c["executed"]:
                rows.append({"scene_kind": sk, "to": t, **c})
    return rows


# A scene's difficulty in [0, 1] read as easy / medium / hard (low <= d < high).
DIFFICULTY_BINS = ((0.0, 1 / 3, "easy"), (1 / 3, 2 / 3, "medium"), (2 / 3, 1.01, "hard"))


def dataset_stats(path) -> dict:
    """Per topology and kind: executed trials, successes, BLC-only successes, errors, and the
    plan chains' missions labelled by the BLC alone (``blc_only``, of them ``blc_only_planned``);
    per scene kind too; and the manifest's fingerprints."""
    from qz_drake.capability.dataset import load_records

    arrays, manifest = load_records(path)
    executed = arrays["status"] == "executed"
    rows = []
    for topology in sorted(set(arrays["topology"].tolist())):
        for kind in sorted(set(arrays["kind"].tolist())):
            sel = (arrays["topology"] == topology) & (arrays["kind"] == kind)
            ex = sel & executed
            if not sel.any():
                continue
            ok = ex & arrays["success"]
            blc = ex & arrays["blc_success"]
            chained = sel & (arrays["status"] == "blc_only")
            rows.append({"topology": topology, "kind": kind, "executed": int(ex.sum()),
                         "successes": int(ok.sum()), "blc_successes": int(blc.sum()),
                         "errors": int((sel & (arrays["status"] == "error")).sum()),
                         "invalid_starts": int((sel & (arrays["status"] == "invalid")).sum()),
                         "blc_only": int(chained.sum()),
                         "blc_only_planned": int((chained & arrays["blc_success"]).sum()),
                         "success_rate": float(ok.sum() / ex.sum()) if ex.any() else None,
                         "blc_disagreement": float(np.mean(arrays["blc_success"][ex] != arrays["success"][ex]))
                         if ex.any() else None})
    scene_rows = []
    for scene_kind in sorted(set(arrays["scene_kind"].tolist())):
        for low, high, name in DIFFICULTY_BINS:
            ex = executed & (arrays["scene_kind"] == scene_kind) & (arrays["difficulty"] >= low) \
                & (arrays["difficulty"] < high)
            if ex.any():
                scene_rows.append({"scene_kind": scene_kind, "difficulty": name, "executed": int(ex.sum()),
                                   "success_rate": float(arrays["success"][ex].mean())})
    kind_rows = []
    for kind in sorted(set(arrays["kind"].tolist())):
        ex = executed & (arrays["kind"] == kind)
        if ex.any():
            b, s = arrays["blc_success"][ex], arrays["success"][ex]
            kind_rows.append({"kind": kind, "executed": int(ex.sum()),
                              "blc_solved_but_robot_failed": float(np.mean(b & ~s)),
                              "disagreement": float(np.mean(b != s))})
    reasons = {}
    for r in arrays["reason"][executed & ~arrays["success"]].tolist():
        reasons[r] = reasons.get(r, 0) + 1
    chained = arrays["status"] == "blc_only"
    refusals = {}
    for r in arrays["reason"][chained & ~arrays["blc_success"]].tolist():
        refusals[r] = refusals.get(r, 0) + 1
    return {"dataset": str(path), "trials": int(len(arrays["index"])), "executed": int(executed.sum()),
            "blc_only": int(chained.sum()), "blc_only_planned": int((chained & arrays["blc_success"]).sum()),
            "blc_only_refusals": refusals,
            "errors": int((arrays["status"] == "error").sum()),
            "invalid_starts": int((arrays["status"] == "invalid").sum()),
            "successes": int(arrays["success"][executed].sum()),
            "rows": rows, "scene_kinds": scene_rows, "kinds": kind_rows, "failure_reasons": reasons,
            "stairs_up": (stairs := stairs_up_rows(arrays, int(manifest.get("seed", 0)))),
            "stairs_up_against_nominal": stairs_up_comparisons(stairs),
            "topologies": topology_rows(arrays), "switches": switch_rows(arrays),
            "seed": manifest.get("seed"), "fingerprint": manifest.get("fingerprint"),
            "fingerprints": manifest.get("fingerprints")}


def paired_against(path, other) -> dict:
    """The same trials in two datasets (the same seed, so a trial index is the same scene,
    heading, topology and kind; e.g. collected again after a BLC change): of the trials
    executed in both, how many each walked, how many only the new one (``path``) or only the
    other walked, and McNemar's exact test of the difference (a two-sided binomial test of the
    discordant trials), over all, per kind and per scene kind and difficulty."""
    from qz_drake.capability.dataset import load_records
    from qz_drake.capability.evaluation import mcnemar_exact_p
    from qz_drake.errors import bad_value

    new, new_manifest = load_records(path)
    old, old_manifest = load_records(other)
    if new_manifest.get("seed") != old_manifest.get("seed"):
        raise bad_value("--against", str(other), f"its seed {old_manifest.get('seed')} is not this dataset's "
                                                  f"{new_manifest.get('seed')}: its trials are other trials")
    where = {int(i): k for k, i in enumerate(old["index"])}
    pairs = [(where[int(i)], k) for k, i in enumerate(new["index"]) if int(i) in where
             and old["status"][where[int(i)]] == "executed" and new["status"][k] == "executed"]
    o = np.array([a for a, _ in pairs], dtype=int)
    n = np.array([b for _, b in pairs], dtype=int)

    def row(mask, **labels):
        was, now = old["success"][o[mask]].astype(bool), new["success"][n[mask]].astype(bool)
        up, down = int(np.sum(now & ~was)), int(np.sum(was & ~now))
        return {**labels, "trials": int(mask.sum()), "other_successes": int(was.sum()),
                "successes": int(now.sum()), "only_this": up, "only_other": down,
                "p_value": mcnemar_exact_p(up, down)}

    everything = np.ones(len(pairs), dtype=bool)
    kinds = new["kind"][n] if len(pairs) else np.array([])
    scene_kinds = new["scene_kind"][n] if len(pairs) else np.array([])
    difficulty = new["difficulty"][n] if len(pairs) else np.array([])
    rows = [row(everything, group="all")]
    rows += [row(kinds == k, group=f"kind {k}") for k in sorted(set(kinds.tolist()))]
    for scene_kind in sorted(set(scene_kinds.tolist())):
        for low, high, name in DIFFICULTY_BINS:
            mask = (scene_kinds == scene_kind) & (difficulty >= low) & (difficulty < high)
            if mask.any():
                rows.append(row(mask, group=f"{scene_kind} {name}"))
    return {"other": str(other), "other_fingerprint": old_manifest.get("fingerprint"), "rows": rows}


def _percent(rate) -> str:
    return "-" if rate is None else f"{100 * rate:.0f} %"


def stats_markdown(stats: dict) -> str:
    """The dataset's summary as Markdown tables (the tables of data/capability/README.md):
    success per topology and kind, per scene kind and difficulty, the BLC-versus-robot
    disagreement per kind, the failure reasons and the topologies going up stairs."""
    lines = [f"{stats['trials']} trials: {stats['executed']} executed, {stats['invalid_starts']} invalid "
             f"starts, {stats['errors']} errors; {stats['successes']} successes "
             f"({_percent(stats['successes'] / stats['executed'] if stats['executed'] else None)} of the "
             f"executed). Dataset fingerprint `{stats['fingerprint']}`.", "",
             "| topology | kind | executed | success | BLC alone | BLC and robot disagree |",
             "| --- | --- | --- | --- | --- | --- |"]
    for row in stats["rows"]:
        blc = row["blc_successes"] / row["executed"] if row["executed"] else None
        lines.append(f"| {row['topology']} | {row['kind']} | {row['executed']} | {_percent(row['success_rate'])} "
                     f"| {_percent(blc)} | {_percent(row['blc_disagreement'])} |")
    lines += ["", "| scene kind | difficulty | executed | success |", "| --- | --- | --- | --- |"]
    for row in stats["scene_kinds"]:
        lines.append(f"| {row['scene_kind']} | {row['difficulty']} | {row['executed']} "
                     f"| {_percent(row['success_rate'])} |")
    lines += ["", "| kind | executed | BLC solved, robot failed | BLC and robot disagree |",
              "| --- | --- | --- | --- |"]
    for row in stats["kinds"]:
        lines.append(f"| {row['kind']} | {row['executed']} | {_percent(row['blc_solved_but_robot_failed'])} "
                     f"| {_percent(row['disagreement'])} |")
    if stats.get("blc_only"):
        lines += ["", f"{stats['blc_only']} missions labelled by the BLC alone (plan chains), "
                      f"{stats['blc_only_planned']} planned.", "",
                  "| topology | kind | labelled by the BLC alone | planned |", "| --- | --- | --- | --- |"]
        for row in stats["rows"]:
            if row["blc_only"]:
                lines.append(f"| {row['topology']} | {row['kind']} | {row['blc_only']} "
                             f"| {_percent(row['blc_only_planned'] / row['blc_only'])} |")
    total = sum(stats["failure_reasons"].values())
    lines += ["", "| failure reason | executed trials | share of failures |", "| --- | --- | --- |"]
    for reason, count in sorted(stats["failure_reasons"].items(), key=lambda item: -item[1]):
        lines.append(f"| {reason} | {count} | {_percent(count / total)} |")
    if stats["stairs_up"]:
        lines += ["", "| rise [m] | topology | up-stairs moves | success | 95 % interval |",
                  "| --- | --- | --- | --- | --- |"]
        for row in stats["stairs_up"]:
            low, high = row["rise_m"]
            lo, hi = row["ci95"]
            lines.append(f"| {low:.2f}-{high:.2f} | {row['topology']} | {row['executed']} "
                         f"| {row['successes']} ({_percent(row['success_rate'])}) "
                         f"| {100 * lo:.0f}-{100 * hi:.0f} % |")
    if stats.get("stairs_up_against_nominal"):
        lines += ["", "| topology | up-stairs moves, rise >= 0.10 m | success | nominal's | Fisher exact p |",
                  "| --- | --- | --- | --- | --- |"]
        for row in stats["stairs_up_against_nominal"]:
            lines.append(f"| {row['topology']} | {row['executed']} | {row['successes']} "
                         f"({_percent(row['successes'] / row['executed'])}) | {row['reference_successes']} / "
                         f"{row['reference_executed']} ({_percent(row['reference_successes'] / row['reference_executed'])}) "
                         f"| {row['p_value']:.2g} |")
    differing = [r for r in stats.get("topologies", []) if r["p_against_reference"] is not None
                 and r["p_against_reference"] < 0.05]
    if stats.get("topologies"):
        lines += ["", "Where a topology's walked share differs from nominal's on the same scene kind and action "
                      f"(Fisher exact p < 0.05; {len(differing)} of "
                      f"{sum(r['p_against_reference'] is not None for r in stats['topologies'])} comparisons):", "",
                  "| scene kind | action | topology | executed | walked | no plan | failed | nominal walked | Fisher p |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        ref = {(r["scene_kind"], r["action"]): r for r in stats["topologies"] if r["topology"] == r["reference"]}
        for row in differing:
            n = ref[(row["scene_kind"], row["action"])]
            lines.append(f"| {row['scene_kind']} | {row['action']} | {row['topology']} | {row['executed']} "
                         f"| {_percent(row['walked_rate'])} | {row['no_plan']} | {row['failed']} "
                         f"| {_percent(n['walked_rate'])} of {n['executed']} | {row['p_against_reference']:.2g} |")
    if stats.get("switches"):
        lines += ["", "| topology switches on | to | executed | done | refused (no plan) | failed |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for row in stats["switches"]:
            lines.append(f"| {row['scene_kind']} | {row['to']} | {row['executed']} | {row['walked']} "
                         f"| {row['no_plan']} | {row['failed']} |")
    if stats.get("against"):
        lines += ["", f"Against `{stats['against']['other']}` (fingerprint `{stats['against']['other_fingerprint']}`), "
                      "the trials executed in both:", "",
                  "| group | executed in both | walked there | walked here | only here | only there "
                  "| McNemar exact p |", "| --- | --- | --- | --- | --- | --- | --- |"]
        for row in stats["against"]["rows"]:
            lines.append(f"| {row['group']} | {row['trials']} | {row['other_successes']} | {row['successes']} "
                         f"| {row['only_this']} | {row['only_other']} | {row['p_value']:.2g} |")
    return "\n".join(lines)
