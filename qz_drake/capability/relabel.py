"""A chained dataset labelled again by the BLC ladder the walks use (issue 54; issue 52's ladder).

A walk's BLC solves a refused mission again on the ladder's rungs; labels of the first solve
alone call "no plan" what the walk plans (40 % of the first-solve refusals of CapPlanner's
round-0 walks planned on a rung). Collecting a dataset again with ``--blc-ladder`` costs as
much as the first time (9 hours for the episode dataset). But a ladder acts only on a refusal:
an episode in which the BLC refused nothing, and nothing failed, is walked the same under any
ladder (the same solves, the same simulation; the ladder's allowance of simulated time is
never reached by a walk that finished its missions). :func:`relabel` therefore copies those
episodes' records and walks only the others again, with the source's settings and the new
ladder. The copies' claim is checked before anything is written: a recertification-like sample
of them is walked again with the new settings and must come out identical (labels, reasons,
iterations and inputs equal; measurements within recertify's tolerance), else the relabelling
is refused with the episode that differs.

The new folder is a dataset like a collection's (its settings the new ones and the source it
was made from; resumable; recertified like any other), labelled by one BLC-robot system.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from qz_drake.capability.collect import (CollectionSummary, LocalPool, RecertifyHooks, _episode_sample,
                                         _protocol_functions, collect_units, compare_records)
from qz_drake.capability.dataset import (MANIFEST, PROVENANCE_SETTINGS, TrialStore, fingerprints, load_records,
                                         read_manifest, settings_dict)
from qz_drake.capability.trials import TrialConfig, stored_trial_config
from qz_drake.errors import ConfigError, bad_value

# Protocols whose episodes can be relabelled this way (chains walked in Drake).
RELABEL_PROTOCOLS = ("episodes", "routes")


def _source(source, hooks):
    """(manifest, protocol, the source's TrialConfig, the settings that are not TrialConfig's)."""
    manifest = read_manifest(source)
    settings = dict(manifest.get("settings", {}))
    protocol = settings.pop("protocol", "moves")
    for key in PROVENANCE_SETTINGS:  # where the dataset came from, not how its trials run
        settings.pop(key, None)
    if protocol not in RELABEL_PROTOCOLS:
        raise bad_value("dataset", str(source), f"is a {protocol} dataset; relabelling takes walked episodes "
                                                f"({', '.join(RELABEL_PROTOCOLS)})")
    if protocol == "routes" and (hooks is None or hooks.protocol != "routes"):
        raise bad_value("dataset", str(source), "a routes dataset is relabelled by `qz capability relabel`, which "
                                                "knows its specs")
    extra = {k: settings.pop(k) for k in (hooks.extra if hooks is not None else ()) if k in settings}
    config = stored_trial_config(settings)
    return manifest, protocol, config, extra


def _unchanged(arrays: dict) -> tuple[set[int], set[int]]:
    """(episodes walked the same under any ladder, the others) of a chained dataset's records:
    an episode is the same when none of its records is a refusal, a failure or a crash (an
    invalid start, whose robot never stood, is the same too)."""
    index = np.asarray(arrays["index"])
    status = np.asarray(arrays["status"]).astype(str)
    executed = status == "executed"
    touched = (executed & ~(np.asarray(arrays["blc_success"]) & np.asarray(arrays["success"]))) | (status == "error")
    others = set(index[touched].tolist())
    return set(index.tolist()) - others, others


def relabel(source, out, *, blc_ladder: str, workers: int = 1, shard_size: int = 100, progress: bool = True,
            command: str = "", limit: int | None = None, log_every: float = 0.0, verify: int = 12,
            hooks: RecertifyHooks | None = None) -> CollectionSummary:
    """The episodes of the dataset ``source`` labelled again with the BLC ladder ``blc_ladder``
    into the folder ``out`` (the module docstring): unchanged episodes copied after ``verify``
    of them were walked again and came out the same, the others walked again; resumable.
    ``hooks``: the specs and worker of a routes dataset (experiments.route_episodes)."""
    clock = time.perf_counter()
    manifest, protocol, old, extra = _source(source, hooks)
    config = TrialConfig(**{**settings_dict(old), "blc_ladder": blc_ladder})
    if config.blc_ladder == old.blc_ladder:
        raise bad_value("--blc-ladder", blc_ladder, f"is the source's own ladder ({old.blc_ladder or 'none'})")
    if isinstance(verify, bool) or not isinstance(verify, int) or verify < 0:
        raise bad_value("--verify", verify, "must be a whole number of episodes, 0 or more")
    arrays, _ = load_records(source)
    seed = int(manifest["seed"])
    same, others = _unchanged(arrays)
    specs_by_index = hooks.specs({**settings_dict(old), **extra}, seed) if protocol == "routes" else None
    settings = settings_dict(config)
    settings.update(protocol=protocol, **extra,
                    relabelled_from={"dataset": str(source), "fingerprint": manifest.get("fingerprint", "")})
    function, crashed = (hooks.function, hooks.crashed) if protocol == "routes" else _protocol_functions("episodes")
    existing = read_manifest(out) if (Path(out) / MANIFEST).is_file() else None
    verified = None
    if existing is None or "relabel_verified" not in existing:  # before anything is written
        verified = _verify(arrays, same, verify, seed, config, workers, function, crashed, specs_by_index)
    store = TrialStore(out, seed=seed, settings=settings, parts=fingerprints(config), command=command)
    try:
        if verified is not None:
            store.note("relabel_verified", verified)
        done = store.done_indices()
        order = np.lexsort((np.asarray(arrays["heading_sample"]), np.asarray(arrays["index"])))
        copies = [{k: v[i] for k, v in arrays.items()} for i in order
                  if int(arrays["index"][i]) in same and int(arrays["index"][i]) not in done]
        for start in range(0, len(copies), shard_size):
            store.append(copies[start:start + shard_size])
    finally:
        store.close()
    specs = _specs(arrays, sorted(others), seed, specs_by_index)
    summary = collect_units(out, specs, seed=seed, settings=settings, config=config, function=function,
                            crashed=crashed, unit="episodes", workers=workers, shard_size=shard_size,
                            progress=progress, command="", limit=limit, log_every=log_every)
    summary.planned += len(same)  # the copies are among its done episodes already
    summary.wall_time_s = time.perf_counter() - clock
    return summary


def _specs(arrays: dict, indices: list[int], seed: int, specs_by_index=None) -> list:
    from qz_drake.capability.episodes import EpisodeSpec

    if specs_by_index is not None:
        return [specs_by_index[e] for e in indices]
    first = {}
    index = np.asarray(arrays["index"])
    for i in np.lexsort((np.asarray(arrays["heading_sample"]), index))[::-1]:
        first[int(index[i])] = int(i)
    return [EpisodeSpec(seed, e, int(arrays["scene"][first[e]]), str(arrays["topology"][first[e]])) for e in indices]


def _verify(arrays, same, count, seed, config, workers, function, crashed, specs_by_index) -> dict:
    """Walks ``count`` of the episodes to be copied again with ``config``; refuses (ConfigError)
    if one differs; returns what the new manifest says of the check."""
    if count == 0 or not same:
        return {"episodes": [], "note": "not verified (--verify 0)" if count == 0 else "nothing to copy"}
    rows = np.flatnonzero(np.isin(arrays["index"], sorted(same)))
    subset = {k: v[rows] for k, v in arrays.items()}
    specs, stored = _episode_sample(subset, count, f"relabel-{config.blc_ladder}", seed, specs_by_index)
    rerun: dict[int, list] = {}
    pool = LocalPool(min(workers, len(specs)), config, 0, function, crashed)
    try:
        pool.run(specs, lambda out: rerun.__setitem__(int(out[0]["index"]), out))
    finally:
        pool.close()
    mismatches, largest = compare_records(stored, rerun, True)
    if mismatches:
        first = mismatches[0]
        raise ConfigError(f"--blc-ladder {config.blc_ladder}: episode {first['index']} refused and failed nothing, "
                          f"yet walked again with the ladder its {', '.join(first['fields'])} differ: the copies' "
                          "claim does not hold here; collect the dataset again instead")
    return {"episodes": sorted(stored), "largest_relative_difference": largest}
