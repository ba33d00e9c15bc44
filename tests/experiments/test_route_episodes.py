"""Episodes from the stances the planners' own walks stood in (issue 54: data from its own routes)."""

import json
import math

import numpy as np
import pytest

from qz_drake.capability.patches import HEADING_STEP
from qz_drake.errors import QzError
from qz_drake.experiments.route_episodes import (ROUTE_SCENE_BASE, RouteSpec, route_commands, route_specs,
                                                 start_window)
from qz_drake.experiments.worlds import TRAINING_SEED_START, make_task, seed_role
from qz_drake.robot.topology import get_topology


def _spec(start=(2.0, 1.0, -0.8), target=(2.0, 0.0, -math.pi / 4), offsets=None, index=0):
    x, y, yaw = start
    offsets = np.zeros((6, 2)) if offsets is None else offsets
    c, s = math.cos(yaw), math.sin(yaw)
    feet_B = get_topology("nominal").footholds_B[:, :2] + offsets
    feet = feet_B @ np.array([[c, s], [-s, c]]) + [x, y]
    return RouteSpec(5, index, ROUTE_SCENE_BASE, "nominal", "stairs", "medium", TRAINING_SEED_START, 1.0,
                     start, tuple((float(a), float(b), 0.03) for a, b in feet), target, "capplanner")


def _same_angle(a, b):
    return abs(math.remainder(a - b, 2 * math.pi)) < 1e-12


def test_every_world_seed_has_one_role_and_the_reserved_ones_are_never_training():
    assert [seed_role(s) for s in (0, 49, 50, 99, 100, 149, 150, 500, 999, 1000, 1003, TRAINING_SEED_START)] == [
        "experiment", "experiment", "reserved", "reserved", "experiment", "experiment", "unassigned", "validation",
        "validation", "tuning", "tuning", "training"]


def test_no_run_walks_a_reserved_world(tmp_path):
    from qz_drake.experiments.fig9 import run_experiment

    with pytest.raises(QzError, match="--first-seed.*seed 50"):
        run_experiment(tmp_path, tasks=3, first_seed=48, progress=False)
    with pytest.raises(QzError, match="--first-seed.*seed 50"):
        run_experiment(tmp_path, tasks=51, progress=False)
    assert not (tmp_path / "results.jsonl").exists()


def test_a_recorded_mission_is_walked_as_the_planners_actions_from_its_measured_stance():
    offsets = np.random.default_rng(0).uniform(-0.03, 0.03, (6, 2))
    # Facing -46 deg, a mission one cell south ending at -45 deg: CapPlanner's turn right, move
    # south, turn left, merged into one BLC mission.
    yaw, got, missions = route_commands(_spec(offsets=offsets), 4.0)
    assert yaw == -0.8
    np.testing.assert_allclose(got, offsets, atol=1e-12)  # the measured feet, as offsets from the footholds
    kinds = [(m.kind, m.direction) for m in missions]
    assert kinds[:3] == [("turn", 1), ("orthogonal", -1), ("turn", 0)]
    assert missions[0].target[:2] == (0.0, 0.0) and _same_angle(missions[0].target[2], -2 * HEADING_STEP)
    assert missions[1].target[:2] == pytest.approx((0.0, -1.0), abs=1e-12)
    assert _same_angle(missions[1].target[2], -2 * HEADING_STEP) and _same_angle(missions[2].target[2], -HEADING_STEP)
    # Then actions drawn as an episode draws them, up to its four moves and turns.
    assert sum(m.kind != "switch" for m in missions) == 4
    assert route_commands(_spec(offsets=offsets), 4.0)[2] == missions  # deterministic
    assert route_commands(_spec(offsets=offsets, index=1), 4.0)[2][:3] == missions[:3]
    # Two cells along a diagonal heading: two diagonal moves, no turn.
    _, _, missions = route_commands(_spec(start=(0.0, 0.0, math.pi / 4), target=(2.0, 2.0, math.pi / 4)), 4.0)
    assert [m.kind for m in missions[:2]] == ["diagonal", "diagonal"]
    assert missions[1].target[:2] == pytest.approx((2.0, 2.0))


def test_the_episode_map_is_the_world_around_the_start_moved_to_its_origin():
    world = make_task("stairs", "medium", TRAINING_SEED_START).heightmap
    x, y = 1.23, -0.71
    window = start_window(world, x, y, 4.0)
    xmin, xmax, ymin, ymax = window.bounds
    assert xmin <= -4.0 + 1e-9 and xmax >= 4.0 - 1e-9 and ymin <= -4.0 + 1e-9 and ymax >= 4.0 - 1e-9
    dx, dy = np.meshgrid(np.linspace(-3.5, 3.5, 15), np.linspace(-3.5, 3.5, 15))
    np.testing.assert_allclose(window.height(dx.ravel(), dy.ravel()), world.height(x + dx.ravel(), y + dy.ravel()),
                               atol=1e-12)
    # Near the world's edge (10 m across) the border runs on.
    edge = start_window(world, x, world.bounds[3] - 1.0, 4.0)
    assert edge.bounds[3] >= 4.0 - 1e-9 and np.isfinite(edge.heights).all()


def _write_walks(folder, records, scale=1.0):
    folder.mkdir(parents=True)
    (folder / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    (folder / "settings.json").write_text(json.dumps({"scale": scale}))
    return folder


def _walk(seed, planner, starts, terrain="stairs"):
    return {"key": f"{terrain}-medium-{seed}-{planner}", "terrain": terrain, "difficulty": "medium", "seed": seed,
            "planner": planner, "reason": "", "success": True,
            "mission_records": [{"start": list(s), "feet": [[0.0, 0.0, 0.0]] * 6, "target": [s[0] + 1, s[1], s[2]],
                                 "topology": "nominal", "outcome": "walked"} for s in starts]}


def test_only_training_worlds_walks_with_missions_give_starts(tmp_path):
    seed = TRAINING_SEED_START
    walks = _write_walks(tmp_path / "ok", [
        _walk(seed, "astar", [(-4.0, 1.0, 0.0), (-3.0, 1.0, 0.0)]),
        # CapPlanner's walk of the same task stands up where A*'s did: one start.
        _walk(seed, "capplanner", [(-4.005, 1.0, 0.0), (-3.0, 0.0, 0.0)]),
        _walk(seed + 1, "astar", [(-4.0, 1.0, 0.0)]),
        {"key": "x", "terrain": "both", "difficulty": "hard", "seed": seed + 2, "reason": "error"},
    ])
    specs, digests = route_specs([walks], 3)
    assert [s.index for s in specs] == [0, 1, 2, 3]
    assert [(s.scene, s.planner, s.start[:2]) for s in specs] == [
        (ROUTE_SCENE_BASE, "astar", (-4.0, 1.0)), (ROUTE_SCENE_BASE, "astar", (-3.0, 1.0)),
        (ROUTE_SCENE_BASE, "capplanner", (-3.0, 0.0)), (ROUTE_SCENE_BASE + 1, "astar", (-4.0, 1.0))]
    assert digests == [[str(walks / "results.jsonl"), digests[0][1]]] and len(digests[0][1]) == 16
    for seed_, role in ((500, "validation"), (60, "reserved"), (1002, "tuning"), (120, "experiment")):
        bad = _write_walks(tmp_path / role, [_walk(seed_, "astar", [(0.0, 0.0, 0.0)])])
        with pytest.raises(QzError, match=f"--walks.*{role} world"):
            route_specs([bad], 0)
    bare = _walk(seed, "astar", [])
    with pytest.raises(QzError, match="--record-missions"):
        route_specs([_write_walks(tmp_path / "bare", [bare])], 0)
    with pytest.raises(QzError, match="--walks.*no results.jsonl"):
        route_specs([tmp_path / "nowhere"], 0)


def test_one_aggregation_round_on_a_tiny_world(tmp_path, capsys):
    """Walks on a training world -> episodes from the stances they stood in -> a model retrained
    on them beside a base dataset: one round of issue 54's data from the planner's own routes."""
    from qz_drake.capability import boosted as B
    from qz_drake.capability.dataset import LEARNER_FIELDS, load_records, load_training_arrays, merge_training_arrays
    from qz_drake.capability.synthetic import synthetic_arrays
    from qz_drake.cli import main
    from qz_drake.experiments.fig9 import ExperimentConfig, read_results, run_experiment
    from qz_drake.experiments.route_episodes import collect_route_episodes

    walks = tmp_path / "walks"
    run_experiment(walks, planners=("astar",), terrains=("stairs",), difficulties=("simple",), tasks=1,
                   config=ExperimentConfig(scale=0.3, record_missions=True), progress=False,
                   first_seed=TRAINING_SEED_START, recordings=0)
    walk, = read_results(walks)
    assert walk["reason"] != "error" and walk["mission_records"]
    routes = tmp_path / "routes"
    summary = collect_route_episodes(routes, [walks], seed=1, limit=1, progress=False)
    assert summary.ran == 1 and summary.planned == len(route_specs([walks], 1)[0])
    arrays, manifest = load_records(routes)
    assert manifest["settings"]["protocol"] == "routes" and manifest["settings"]["walks"][0][0].endswith("results.jsonl")
    assert set(arrays["index"]) == {0} and list(arrays["heading_sample"]) == list(range(len(arrays["index"])))
    assert set(arrays["scene"]) == {ROUTE_SCENE_BASE} and set(arrays["scene_kind"]) == {"fig9_stairs"}
    first = walk["mission_records"][0]
    # The first mission starts where the walk's did: its feet, in the heading frame, are the walk's.
    assert arrays["heading"][0] == pytest.approx(first["start"][2], abs=1e-6)
    assert arrays["status"][0] == "executed"
    # Walks that changed since are not the collection's starts: a resume from them is refused.
    with (walks / "results.jsonl").open("a") as f:
        f.write(json.dumps(dict(walk, key="again")) + "\n")
    with pytest.raises(QzError, match="settings.walks"):
        collect_route_episodes(routes, [walks], seed=1, limit=1, progress=False)
    # Retrained on a base collection and the routes' episodes together (the base here a
    # synthetic dataset standing in for the episode collection, labelled by the same system).
    learned, route_manifest = load_training_arrays(routes)
    base, _ = synthetic_arrays(scenes=12, headings=4, topologies=("nominal",), seed=2)
    n = len(base["scene"])
    base.update(direction=np.asarray(base["direction"]), index=np.arange(n), reason=np.full(n, ""),
                difficulty=np.zeros(n))
    base = {k: np.asarray(base[k]) for k in LEARNER_FIELDS}
    base_manifest = {"fingerprint": "base", "fingerprints": route_manifest["fingerprints"],
                     "settings": {**route_manifest["settings"], "protocol": "episodes"}}
    merged, merged_manifest = merge_training_arrays([("base", base, base_manifest), (str(routes), learned, route_manifest)])
    assert len(merged["scene"]) == n + len(learned["scene"])
    assert [s["records"] for s in merged_manifest["sources"]] == [n, len(learned["scene"])]
    result = B.train_boosted(merged, fingerprint=merged_manifest["fingerprint"],
                             fingerprints=merged_manifest["fingerprints"],
                             config=B.BoostedConfig(members=1, max_iter=10, min_samples_leaf=2))
    assert any(ROUTE_SCENE_BASE in ids for ids in result.card["split"].values())
    # Another BLC-robot system, or the same scenes twice, is refused by name.
    other = {**base_manifest, "fingerprints": {**base_manifest["fingerprints"], "blc": "0123456789abcdef"}}
    with pytest.raises(QzError, match="--dataset.*blc"):
        merge_training_arrays([("base", base, other), (str(routes), learned, route_manifest)])
    laddered = {**base_manifest, "settings": {**base_manifest["settings"], "blc_ladder": "cycles+1"}}
    with pytest.raises(QzError, match="settings.blc_ladder"):
        merge_training_arrays([("base", base, laddered), (str(routes), learned, route_manifest)])
    with pytest.raises(QzError, match=f"scene {ROUTE_SCENE_BASE}"):
        merge_training_arrays([("a", learned, route_manifest), ("b", learned, route_manifest)])
    # The command refuses a validation world's walks in one line, exit 2.
    bad = _write_walks(tmp_path / "validation", [_walk(500, "astar", [(0.0, 0.0, 0.0)])])
    assert main(["capability", "collect-routes", "--walks", str(bad), "--out", str(tmp_path / "never")]) == 2
    err = capsys.readouterr().err.strip()
    assert "validation world" in err and len(err.splitlines()) == 1
