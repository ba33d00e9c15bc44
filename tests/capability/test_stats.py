"""The dataset summary's topology comparison on stairs (paper 000: bend-inside legs are safer
going up stairs, a longer stance better on higher ones): which trials count as going up a
flight, the rise bins, and the Wilson intervals that say how sure each rate is."""

import numpy as np
import pytest

from qz_drake.capability.stats import stairs_up_rows, wilson_interval
from qz_drake.capability.scenes import scene_for, scene_recipe


def test_wilson_interval_matches_the_textbook_values():
    lo, hi = wilson_interval(5, 10)
    assert lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0
    assert wilson_interval(0, 0) == (0.0, 1.0)


def test_only_moves_heading_up_a_rising_flight_are_compared():
    # The first rising flight of seed 0 in the 0.10-0.16 m bin: moves facing +x go up it.
    scene = next(i for i in range(2000) if scene_recipe(0, i)[0] == "stairs"
                 and 0.10 <= scene_for(0, i).params["rise"] < 0.16)
    rows = {
        "status": ["executed", "executed", "executed", "invalid", "executed"],
        "scene_kind": ["stairs"] * 5,
        "kind": ["orthogonal", "diagonal", "orthogonal", "orthogonal", "turn"],
        "scene": [scene] * 5,
        "heading": [0.0, np.radians(45), np.pi, 0.0, 0.0],  # up, up, away, -, a turn
        "topology": ["front_bend", "front_bend", "front_bend", "front_bend", "front_bend"],
        "success": [True, False, True, True, True],
    }
    arrays = {k: np.asarray(v) for k, v in rows.items()}
    [row] = stairs_up_rows(arrays, seed=0)
    assert row["rise_m"] == [0.10, 0.16] and row["topology"] == "front_bend"
    assert row["executed"] == 2 and row["successes"] == 1 and row["success_rate"] == 0.5
    assert row["ci95"] == list(wilson_interval(1, 2))


def test_markdown_summary_lists_every_row_and_the_failure_shares():
    from qz_drake.capability.stats import stats_markdown

    stats = {
        "trials": 12, "executed": 10, "invalid_starts": 2, "errors": 0, "successes": 6, "fingerprint": "abc",
        "rows": [{"topology": "nominal", "kind": "turn", "executed": 10, "successes": 6, "blc_successes": 8,
                  "success_rate": 0.6, "blc_disagreement": 0.2}],
        "scene_kinds": [{"scene_kind": "stairs", "difficulty": "hard", "executed": 10, "success_rate": 0.6}],
        "kinds": [{"kind": "turn", "executed": 10, "blc_solved_but_robot_failed": 0.2, "disagreement": 0.2}],
        "failure_reasons": {"slip": 1, "blc_time_limit": 3},
        "stairs_up": [],
    }
    text = stats_markdown(stats)
    assert "| nominal | turn | 10 | 60 % | 80 % | 20 % |" in text
    assert "| stairs | hard | 10 | 60 % |" in text
    # Reasons by count, each with its share of the failures.
    assert text.index("| blc_time_limit | 3 | 75 % |") < text.index("| slip | 1 | 25 % |")
    assert "rise [m]" not in text


def test_topologies_are_compared_with_nominal_on_the_higher_stairs_by_fishers_test():
    from scipy.stats import fisher_exact

    from qz_drake.capability.stats import stairs_up_comparisons

    rows = [{"rise_m": [0.04, 0.10], "topology": "front_bend", "executed": 30, "successes": 30},
            {"rise_m": [0.10, 0.16], "topology": "front_bend", "executed": 30, "successes": 12},
            {"rise_m": [0.16, 0.27], "topology": "front_bend", "executed": 40, "successes": 8},
            {"rise_m": [0.04, 0.10], "topology": "nominal", "executed": 30, "successes": 0},
            {"rise_m": [0.10, 0.16], "topology": "nominal", "executed": 30, "successes": 5},
            {"rise_m": [0.16, 0.27], "topology": "nominal", "executed": 40, "successes": 1}]
    [row] = stairs_up_comparisons(rows)
    # The low stairs are left out of both; the higher two bins pooled.
    assert (row["topology"], row["successes"], row["executed"]) == ("front_bend", 20, 70)
    assert (row["reference_successes"], row["reference_executed"]) == (6, 70)
    assert row["p_value"] == pytest.approx(fisher_exact([[20, 50], [6, 64]])[1])
    assert row["p_value"] < 0.01
    assert stairs_up_comparisons(rows[:3]) == []  # no nominal rows: nothing to compare with


def test_two_collections_of_the_same_trials_are_compared_pair_by_pair(monkeypatch, capsys):
    """`qz capability stats NEW --against OLD`: trials matched by index (executed in both),
    who walked what, McNemar's exact test of the discordant pairs; another seed is refused."""
    from scipy.stats import binomtest

    from qz_drake.capability import dataset
    from qz_drake.cli import main

    def records(success, status=None, index=None, seed=0):
        m = len(success)
        arrays = {"index": np.asarray(index if index is not None else np.arange(m)),
                  "status": np.asarray(status or ["executed"] * m), "success": np.asarray(success, dtype=bool),
                  "kind": np.asarray(["orthogonal", "turn"] * (m // 2)),
                  "scene_kind": np.asarray(["gap"] * m), "difficulty": np.full(m, 0.9)}
        return arrays, {"seed": seed, "fingerprint": f"fp{seed}{m}"}

    # Trials 0-7 in both (trial 7 invalid in the new one), trial 8 only in the old one.
    old = records([False, False, False, False, True, True, False, True, True], index=np.arange(9))
    new = records([True, True, True, False, True, False, False, True], index=np.arange(8),
                  status=["executed"] * 7 + ["invalid"])
    other_seed = records([True] * 8, seed=1)
    folders = {"new": new, "old": old, "seed1": other_seed}
    monkeypatch.setattr(dataset, "load_records", lambda path: folders[str(path)])
    from qz_drake.capability.stats import paired_against

    result = paired_against("new", "old")
    everything = result["rows"][0]
    assert everything["group"] == "all" and everything["trials"] == 7
    assert (everything["other_successes"], everything["successes"]) == (2, 4)
    assert (everything["only_this"], everything["only_other"]) == (3, 1)
    assert everything["p_value"] == pytest.approx(binomtest(3, 4, 0.5).pvalue)
    groups = {r["group"]: r for r in result["rows"]}
    assert groups["kind orthogonal"]["trials"] + groups["kind turn"]["trials"] == 7
    assert groups["gap hard"]["trials"] == 7

    monkeypatch.setattr("qz_drake.capability.stats.dataset_stats", lambda path: {
        "trials": 8, "executed": 7, "invalid_starts": 1, "errors": 0, "successes": 4, "fingerprint": "x",
        "rows": [], "scene_kinds": [], "kinds": [], "failure_reasons": {}, "stairs_up": []})
    assert main(["capability", "stats", "new", "--against", "old", "--markdown"]) == 0
    assert "| all | 7 | 2 | 4 | 3 | 1 |" in capsys.readouterr().out
    assert main(["capability", "stats", "new", "--against", "seed1"]) == 2
    assert "--against" in capsys.readouterr().err
    # Without --json or --markdown: the plain summary, the comparison included.
    monkeypatch.setattr("qz_drake.capability.stats.dataset_stats", lambda path: {
        "dataset": path, "trials": 8, "executed": 7, "invalid_starts": 1, "errors": 0, "successes": 4,
        "fingerprint": "x", "rows": [], "scene_kinds": [], "kinds": [], "failure_reasons": {}, "stairs_up": []})
    assert main(["capability", "stats", "new", "--against", "old"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("new: 7 executed, 1 invalid starts, 0 errors, 4 successes") and "all: 4/7 here" in out


def test_topologies_are_compared_per_scene_kind_with_three_outcomes_and_switches_apart():
    from scipy.stats import fisher_exact

    from qz_drake.capability.stats import stats_markdown, switch_rows, topology_rows

    def records(scene_kind, topology, kind, walked, no_plan, failed):
        n = walked + no_plan + failed
        return {"scene_kind": [scene_kind] * n, "topology": [topology] * n, "kind": [kind] * n,
                "status": ["executed"] * n, "success": [True] * walked + [False] * (no_plan + failed),
                "blc_success": [True] * walked + [False] * no_plan + [True] * failed}

    parts = [records("box_field", "nominal", "orthogonal", 30, 8, 2), records("box_field", "hind_bend", "diagonal", 15, 25, 0),
             records("box_field", "hind_bend", "turn", 10, 0, 0), records("flat", "nominal", "orthogonal", 20, 0, 0),
             records("box_field", "split_up", "switch", 3, 2, 1)]
    arrays = {k: np.array(sum((p[k] for p in parts), [])) for k in parts[0]}
    rows = topology_rows(arrays)
    hind = next(r for r in rows if (r["scene_kind"], r["action"], r["topology"]) == ("box_field", "moves", "hind_bend"))
    assert (hind["executed"], hind["walked"], hind["no_plan"], hind["failed"]) == (40, 15, 25, 0)
    assert hind["p_against_reference"] == pytest.approx(fisher_exact([[15, 25], [30, 10]])[1])
    nominal = next(r for r in rows if (r["scene_kind"], r["topology"]) == ("box_field", "nominal"))
    assert nominal["failed"] == 2 and nominal["p_against_reference"] is None
    # hind_bend's turns have no nominal turns to be compared with; switches are not actions.
    turns = next(r for r in rows if r["action"] == "turns")
    assert turns["p_against_reference"] is None
    assert not any(r["topology"] == "split_up" for r in rows)
    assert switch_rows(arrays) == [{"scene_kind": "box_field", "to": "split_up", "executed": 6, "walked": 3,
                                    "no_plan": 2, "failed": 1}]
    text = stats_markdown({"trials": 0, "executed": 1, "invalid_starts": 0, "errors": 0, "successes": 0,
                           "fingerprint": "x", "rows": [], "scene_kinds": [], "kinds": [], "failure_reasons": {},
                           "stairs_up": [], "topologies": rows, "switches": switch_rows(arrays)})
    assert "| box_field | moves | hind_bend | 40 | 38 % | 25 | 0 | 75 % of 40 |" in text
    assert "| box_field | split_up | 6 | 3 | 2 | 1 |" in text
