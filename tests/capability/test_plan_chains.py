"""Plan chains (issues 53 and 54): missions labelled by the BLC alone, chained from its own plans."""

import dataclasses
import json
import math

import numpy as np
import pytest

from qz_drake.capability.episodes import EPISODE_HALF_SIZE, SCENE_EDGE_MARGIN, EpisodeSpec
from qz_drake.capability.patches import HEADING_STEP, move_distance
from qz_drake.capability.plan_chains import BLC_ONLY, CHAIN_MISSIONS, run_plan_chain
from qz_drake.capability.scenes import scene_recipe
from qz_drake.capability.trials import TrialConfig
from qz_drake.robot.topology import TOPOLOGY_NAMES


def _flat_chain(seed: int = 0, topology: str = "nominal") -> EpisodeSpec:
    scene = next(i for i in range(200) if scene_recipe(seed, i)[0] == "flat")
    return EpisodeSpec(seed, scene * 6 + TOPOLOGY_NAMES.index(topology), scene, topology)


def _split_up_chain() -> EpisodeSpec:
    """Seed 35's first scene (flat: quick to plan) as a split_up plan chain."""
    assert scene_recipe(35, 0)[0] == "flat"
    return EpisodeSpec(35, TOPOLOGY_NAMES.index("split_up"), 0, "split_up")


def test_a_chain_on_flat_ground_plans_every_command_from_where_the_last_plan_ended():
    records = run_plan_chain(_split_up_chain())
    moves = [r for r in records if r["kind"] != "switch"]
    assert len(moves) == CHAIN_MISSIONS
    assert [r["status"] for r in records] == [BLC_ONLY] * len(records)
    assert all(r["blc_success"] for r in records), [r["blc_reason"] for r in records]
    assert [r["heading_sample"] for r in records] == list(range(len(records)))
    # Nothing is walked: no execution label, no simulated time.
    assert not any(r["success"] for r in records) and all(r["sim_time_s"] == 0 for r in records)
    x = y = 0.0
    yaw = records[0]["heading"]
    for k, r in enumerate(records):
        assert r["patch"].shape == (20, 20) and np.abs(r["patch"]).max() < 1e-6  # flat
        # Each command starts where the plan before it ends (its heading within a few degrees).
        assert math.remainder(r["heading"] - yaw, 2 * math.pi) == pytest.approx(0, abs=0.05)
        if r["kind"] == "switch":
            assert r["blc_iterations"] == 0 and r["topology"] != records[k - 1]["topology"]
            assert r["direction"] == TOPOLOGY_NAMES.index(records[k - 1]["topology"])
            continue
        assert r["blc_iterations"] > 0
        if r["kind"] == "turn":
            yaw += HEADING_STEP if r["direction"] == 0 else -HEADING_STEP
        else:
            assert r["kind"] == ("diagonal" if round(yaw / HEADING_STEP) % 2 else "orthogonal")
            x += move_distance(r["kind"]) * math.cos(yaw)
            y += move_distance(r["kind"]) * math.sin(yaw)
        assert max(abs(x), abs(y)) <= EPISODE_HALF_SIZE - SCENE_EDGE_MARGIN + 1e-9
    # The feet differ from mission to mission: each starts from the last plan's end stance.
    feet = [r["feet"] for r in records]
    assert any(np.abs(a - b).max() > 0.02 for a, b in zip(feet, feet[1:]))


def test_a_refused_mission_leaves_the_robot_where_it_stood_and_the_chain_goes_on():
    # One Ipopt iteration plans nothing: every command is refused, each from the same stance.
    config = dataclasses.replace(TrialConfig(), blc_max_iterations=1)
    records = run_plan_chain(_flat_chain(topology="hind_bend"), config)
    moves = [r for r in records if r["kind"] != "switch"]
    assert moves and not any(r["blc_success"] for r in moves)
    assert {r["reason"] for r in moves} == {"blc_time_limit"}
    assert all("Max iteration" in r["blc_reason"] for r in moves)
    # A refused move leaves the stance as it was: the next command starts from it (a switch,
    # which needs no Ipopt, plans and moves the feet to the new topology's footholds).
    pairs = [(a, b) for a, b in zip(records, records[1:]) if a["kind"] != "switch"]
    assert pairs
    for a, b in pairs:
        np.testing.assert_array_equal(b["feet"], a["feet"])
        assert b["heading"] == a["heading"]
    # A refused command is closed at that stance (until a switch): forward, left and right
    # once each, and a stance from which all three are refused ends the chain.
    stances, current = [], []
    for r in records:
        if r["kind"] == "switch":
            if r["blc_success"]:
                stances.append(current)
                current = []
            continue
        current.append((r["kind"] != "turn", r["direction"]))
    stances.append(current)
    assert all(len(set(commands)) == len(commands) for commands in stances)
    assert len(stances[-1]) == 3 and len(moves) < CHAIN_MISSIONS


# Two worker processes (the collection's and the recertification's): about 15 s. The chain
# itself is the fast tests' (test_a_chain_on_flat_ground...), the protocols' shared storage and
# recertification the episodes' (tests/capability/test_episodes.py).
@pytest.mark.slow
def test_a_plan_chain_collection_is_stored_beside_the_executed_labels_and_recertified(tmp_path):
    from qz_drake.capability.collect import collect, recertify
    from qz_drake.capability.dataset import load_records, load_training_arrays
    from qz_drake.capability.stats import dataset_stats

    out = tmp_path / "plans"
    summary = collect(out, seed=35, scenes=1, topologies=["split_up"], protocol="plans",
                      progress=False, shard_size=5)
    assert summary.ran == 1
    arrays, manifest = load_records(out)
    assert manifest["settings"]["protocol"] == "plans" and set(arrays["status"]) == {BLC_ONLY}
    # The worker ran the chain this process runs: the same records (deterministic).
    again = run_plan_chain(_split_up_chain())
    assert arrays["feet"].tolist() == [r["feet"].tolist() for r in again]
    assert list(arrays["blc_success"]) == [r["blc_success"] for r in again]
    assert list(arrays["heading_sample"]) == list(range(len(arrays["index"])))
    assert sum(s.get("blc_only", 0) for s in manifest["shards"]) == len(arrays["index"])
    stats = dataset_stats(out)
    assert stats["blc_only"] == len(arrays["index"]) and stats["executed"] == 0
    assert stats["blc_only_planned"] == int(arrays["blc_success"].sum())
    # The networks learn executed missions only: a chain's records carry no execution label.
    with pytest.raises(Exception, match="no executed"):
        load_training_arrays(out)
    # Recertified like an episode dataset: whole chains run again and compared.
    manifest = json.loads((out / "manifest.json").read_text())
    current = dict(manifest["fingerprints"])
    manifest["fingerprints"]["blc"] = "0123456789abcdef"
    (out / "manifest.json").write_text(json.dumps(manifest))
    result = recertify(out, sample=1)
    assert result.identical and result.rerun == 1 and result.unit == "chains", result.mismatches
    assert json.loads((out / "manifest.json").read_text())["fingerprints"] == current
