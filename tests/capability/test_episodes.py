"""Capability episodes (issue 37): chained missions walked like a walk, one label each."""

import math

import numpy as np
import pytest

from qz_drake.capability.episodes import (EPISODE_HALF_SIZE, EPISODE_MISSIONS, SCENE_EDGE_MARGIN,
                                          SWITCH_PROBABILITY, EpisodeSpec, episode_commands,
                                          episode_specs, padded_scene_map, run_episode)
from qz_drake.capability.patches import HEADING_STEP, move_distance
from qz_drake.capability.scenes import SCENE_HALF_SIZE, scene_for, scene_recipe
from qz_drake.config import SuccessCriteria
from qz_drake.robot.topology import TOPOLOGY_NAMES


def _flat_episode(seed: int = 0) -> EpisodeSpec:
    scene = next(i for i in range(200) if scene_recipe(seed, i)[0] == "flat")
    return EpisodeSpec(seed, scene * 6, scene, "nominal")


def _flat_episode_with_switch() -> EpisodeSpec:
    # Seed 2's flat scene 115: forward, forward, turn, switch to hind_bend, turn.
    assert scene_recipe(2, 115)[0] == "flat"
    return EpisodeSpec(2, 115 * 6, 115, "nominal")


def test_commands_chain_like_the_planners_actions_and_stay_on_the_scene():
    for spec in episode_specs(3, 40):
        heading, offsets, missions = episode_commands(spec, EPISODE_HALF_SIZE)
        moves = [m for m in missions if m.kind != "switch"]
        assert len(moves) == EPISODE_MISSIONS and offsets.shape == (6, 2)
        assert episode_commands(spec, EPISODE_HALF_SIZE)[2] == missions  # deterministic
        assert missions[0].kind != "switch" and missions[-1].kind != "switch"
        x, y, yaw = 0.0, 0.0, heading
        topology = spec.topology
        for m in missions:
            h = round(yaw / HEADING_STEP) % 8
            if m.kind == "switch":
                # In place, to another topology; direction: the one it leaves.
                assert m.target == pytest.approx((x, y, yaw))
                assert m.direction == TOPOLOGY_NAMES.index(topology) and m.topology != topology
                topology = m.topology
                continue
            assert m.topology == topology
            if m.kind == "turn":
                # 45 deg left (0) or right (1) in place.
                step = 1 if m.direction == 0 else -1
                assert m.target[:2] == pytest.approx((x, y))
                assert math.remainder(m.target[2] - yaw - step * HEADING_STEP, 2 * math.pi) == pytest.approx(0)
            else:
                # Forward one cell along the heading: orthogonal on an axis, diagonal between.
                assert m.kind == ("diagonal" if h % 2 else "orthogonal") and m.direction == -1
                d = move_distance(m.kind)
                assert m.target[:2] == pytest.approx((x + d * math.cos(yaw), y + d * math.sin(yaw)))
                assert m.target[2] == pytest.approx(yaw)
            assert max(abs(m.target[0]), abs(m.target[1])) <= EPISODE_HALF_SIZE - SCENE_EDGE_MARGIN + 1e-9
            x, y, yaw = m.target
    with pytest.raises(Exception, match="topologies"):
        episode_specs(0, 1, topologies=["upside_down"])


def test_most_commands_are_forward_moves_as_in_the_planners_routes():
    kinds = [m.kind for spec in episode_specs(1, 50) for m in episode_commands(spec, EPISODE_HALF_SIZE)[2]]
    moves = [k for k in kinds if k != "switch"]
    turns = moves.count("turn") / len(moves)
    assert 0.3 < turns < 0.5, turns  # 40 % drawn, a few more where a move would leave the map
    # A switch before each move or turn but the first.
    switches = kinds.count("switch") / (len(moves) * (EPISODE_MISSIONS - 1) / EPISODE_MISSIONS)
    assert abs(switches - SWITCH_PROBABILITY) < 0.05, switches


def test_the_scene_map_is_extended_by_continuing_its_border():
    scene = scene_for(2, 3)
    hm = scene.heightmap
    padded = padded_scene_map(hm, EPISODE_HALF_SIZE)
    assert padded.resolution == hm.resolution
    (xmin, xmax), (ymin, ymax) = (padded.x_coords[[0, -1]], padded.y_coords[[0, -1]])
    assert xmin <= -EPISODE_HALF_SIZE + 1e-9 and xmax >= EPISODE_HALF_SIZE - 1e-9
    assert ymin <= -EPISODE_HALF_SIZE + 1e-9 and ymax >= EPISODE_HALF_SIZE - 1e-9
    # The scene's own cells are unchanged; beyond them each row and column runs on.
    i0 = int(round((hm.origin[0] - padded.origin[0]) / hm.resolution))
    j0 = int(round((hm.origin[1] - padded.origin[1]) / hm.resolution))
    H, W = hm.heights.shape
    np.testing.assert_array_equal(padded.heights[j0:j0 + H, i0:i0 + W], hm.heights)
    np.testing.assert_array_equal(padded.heights[j0:j0 + H, 0], hm.heights[:, 0])
    np.testing.assert_array_equal(padded.heights[-1, i0:i0 + W], hm.heights[-1])
    assert SCENE_HALF_SIZE < EPISODE_HALF_SIZE


def test_an_episode_on_flat_ground_labels_every_mission_and_switch_from_where_it_starts():
    spec = _flat_episode_with_switch()
    heading, _, missions = episode_commands(spec, EPISODE_HALF_SIZE)
    records = run_episode(spec)
    assert [r["status"] for r in records] == ["executed"] * len(missions)
    assert all(r["success"] for r in records), [(r["reason"], r["message"]) for r in records]
    assert [r["heading_sample"] for r in records] == list(range(len(missions)))
    assert [r["kind"] for r in records] == [m.kind for m in missions]
    assert "switch" in [m.kind for m in missions]
    for k, r in enumerate(records):
        assert r["patch"].shape == (20, 20) and np.abs(r["patch"]).max() < 1e-6  # flat
        assert r["topology"] == missions[k].topology
        if r["kind"] == "switch":
            # Its own sample: from the topology it leaves, over the switch's own stretch (six
            # legs moved in two tripods, no BLC solve), back where it stood.
            assert r["direction"] == TOPOLOGY_NAMES.index(missions[k - 1].topology) and r["topology"] == "hind_bend"
            assert r["blc_success"] and r["blc_iterations"] == 0 and 3.0 < r["sim_time_s"] < 6.0
            assert r["final_xy_error_m"] < 0.02
            continue
        assert r["blc_success"] and r["blc_iterations"] > 0 and r["sim_time_s"] > 1.0
        assert r["final_xy_error_m"] < 0.15
        # Each mission starts where the last one took the robot: its heading is the last
        # target's, and its feet are where the last mission put them (no standing pose).
        start_yaw = heading if k == 0 else missions[k - 1].target[2]
        assert math.remainder(r["heading"] - start_yaw, 2 * math.pi) == pytest.approx(0, abs=0.05)
    feet = [r["feet"] for r in records]
    assert any(np.abs(a - b).max() > 0.02 for a, b in zip(feet, feet[1:]))


def test_the_first_failed_mission_ends_the_episode_with_its_reason():
    # A verdict that allows no tracking error at all: the first mission's joints lag their
    # references by a fraction of a degree, the walk stops at its first check.
    strict = SuccessCriteria(max_joint_error_deg=1e-3)
    records = run_episode(_flat_episode(), criteria=strict)
    assert len(records) == 1
    assert not records[0]["success"] and records[0]["reason"] == "tracking"
    assert "off its reference" in records[0]["message"]


@pytest.fixture(scope="module")
def one_episode(tmp_path_factory):
    """Seed 5's first scene walked as one nominal episode (all four missions walk: measured)."""
    from qz_drake.capability.collect import collect

    out = tmp_path_factory.mktemp("episodes") / "one"
    summary = collect(out, seed=5, scenes=1, topologies=["nominal"], protocol="episodes",
                      progress=False, shard_size=10)
    assert summary.planned == 1 and summary.ran == 1
    return out


def test_an_episode_collection_stores_a_record_per_mission_and_resumes(one_episode, tmp_path):
    import json
    import shutil

    from qz_drake.capability.collect import collect, recertify
    from qz_drake.capability.dataset import load_records

    out = one_episode
    arrays, manifest = load_records(out)
    assert manifest["settings"]["protocol"] == "episodes"
    assert len(arrays["index"]) == EPISODE_MISSIONS and set(arrays["index"]) == {0}
    assert list(arrays["heading_sample"]) == list(range(EPISODE_MISSIONS))
    assert list(arrays["status"]) == ["executed"] * EPISODE_MISSIONS and arrays["success"].all()
    _, _, missions = episode_commands(EpisodeSpec(5, 0, 0, "nominal"), EPISODE_HALF_SIZE)
    assert list(arrays["kind"]) == [m.kind for m in missions]
    again = collect(out, seed=5, scenes=1, topologies=["nominal"], protocol="episodes", progress=False)
    assert again.already_done == 1 and again.ran == 0
    # A code change that keeps behaviour is certified by re-running whole episodes and
    # comparing their record lists; the dataset then resumes under the new code.
    manifest = json.loads((out / "manifest.json").read_text())
    current = dict(manifest["fingerprints"])
    moved = tmp_path / "moved"
    shutil.copytree(out, moved)
    manifest["fingerprints"]["controller"] = "0123456789abcdef"
    (moved / "manifest.json").write_text(json.dumps(manifest))
    result = recertify(moved, sample=1)
    assert result.changed == ["controller"] and result.rerun == 1 and result.identical, result.mismatches
    assert result.unit == "episodes"
    assert json.loads((moved / "manifest.json").read_text())["fingerprints"] == current
    # The certified code to tell a machine's difference from a change's must be a source tree.
    with pytest.raises(Exception, match="--reference-code"):
        recertify(moved, reference_code=tmp_path)
    with pytest.raises(Exception, match="--kinds"):
        collect(tmp_path / "other", scenes=1, kinds=["turn"], protocol="episodes", progress=False)
    with pytest.raises(Exception, match="--protocol"):
        collect(tmp_path / "other", scenes=1, protocol="walks", progress=False)


@pytest.mark.slow
def test_an_episode_the_code_no_longer_reproduces_is_refused_with_its_mission(one_episode, tmp_path):
    import json
    import shutil

    from qz_drake.capability.collect import recertify

    altered = tmp_path / "altered"
    shutil.copytree(one_episode, altered)
    manifest = json.loads((altered / "manifest.json").read_text())
    manifest["fingerprints"]["controller"] = "0123456789abcdef"
    (altered / "manifest.json").write_text(json.dumps(manifest))
    shard = next(altered.glob("shard-*.npz"))
    with np.load(shard) as f:
        data = {k: f[k] for k in f.files}
    data["blc_iterations"] = data["blc_iterations"].copy()
    data["blc_iterations"][2] += 1
    np.savez(shard, **data)
    refused = recertify(altered, sample=1)
    assert not refused.identical and refused.mismatches[0]["fields"] == ["blc_iterations"]
    assert refused.mismatches[0]["mission"] == 2
    assert json.loads((altered / "manifest.json").read_text()) == manifest  # nothing written


@pytest.mark.slow  # a second interpreter walks the episode again on a copy of the code: about a minute
def test_an_episode_dataset_is_recertified_with_the_certified_code_telling_a_machines_difference(
        one_episode, tmp_path, certified_code):
    import json
    import shutil

    from qz_drake.capability.collect import recertify

    certified, fingerprints_of = certified_code
    manifest = json.loads((one_episode / "manifest.json").read_text())
    settings = {k: v for k, v in manifest["settings"].items() if k != "protocol"}
    # Stored as another processor might have stored it: one mission's iteration count off by one.
    data = tmp_path / "collected_elsewhere"
    shutil.copytree(one_episode, data)
    manifest["fingerprints"].update(fingerprints_of(settings))
    (data / "manifest.json").write_text(json.dumps(manifest))
    shard = data / manifest["shards"][0]["file"]
    with np.load(shard) as stored:
        arrays = {k: stored[k] for k in stored.files}
    arrays["blc_iterations"] = arrays["blc_iterations"] + np.eye(1, len(arrays["index"]), dtype=int)[0]
    np.savez_compressed(shard, **arrays)

    refused = recertify(data, sample=1)
    assert not refused.identical and [m["index"] for m in refused.mismatches] == [0]
    # The certified code walks the episode here as the running code does: the machine's.
    result = recertify(data, sample=1, reference_code=certified)
    assert result.identical and result.changed == ["verdict"], result.mismatches
    assert [m["index"] for m in result.machine_differences] == [0] and result.unit == "episodes"
