"""Scenes of paper 000 III-B and the walk-like scenes of issue 37: named functions of a
difficulty and a seed, centred on the start."""

import math

import numpy as np
import pytest

from qz_drake.capability.scenes import (FIG9_BOX_HEIGHT, FIG9_BOX_SHARE, FIG9_HILL_WIDTH, FIG9_LANDING, FIG9_RISE,
                                        FIG9_RUN, FIG9_STEPS, IRREGULAR_KINDS, PAPER_KINDS, PIT_REACH,
                                        REGULAR_KINDS, SCENE_FUNCTIONS, SCENE_HALF_SIZE, SCENE_KINDS,
                                        SCENE_SEED_START, WALK_KINDS, make_scene, scene_for, scene_recipe)
from qz_drake.errors import QzError

# The farthest a foot of a standing start lies from its centre: split_up's foothold (0.83 m)
# plus the trials' foot offsets (0.06 m) and the foot's radius. [m]
FOOTPRINT_RADIUS = 0.92


@pytest.mark.parametrize("kind", sorted(SCENE_FUNCTIONS))
def test_every_kind_is_a_centred_finite_map_that_grows_harder(kind):
    easy, hard = make_scene(kind, 0.0, 7), make_scene(kind, 1.0, 7)
    for scene in (easy, hard):
        xmin, xmax, ymin, ymax = scene.heightmap.bounds
        assert xmin < -SCENE_HALF_SIZE + 0.1 and xmax > SCENE_HALF_SIZE - 0.1
        assert ymin < -SCENE_HALF_SIZE + 0.1 and ymax > SCENE_HALF_SIZE - 0.1
        assert np.all(np.isfinite(scene.heightmap.heights))
    if kind != "flat":
        spread = [np.mean(np.abs(s.heightmap.heights)) for s in (easy, hard)]
        assert spread[1] > spread[0]


def test_scenes_are_reproducible_half_walk_like_and_the_paper_half_split_70_30():
    a, b = scene_for(3, 11), scene_for(3, 11)
    assert a.kind == b.kind and np.array_equal(a.heightmap.heights, b.heightmap.heights)
    assert sum(share for _, share in SCENE_KINDS) == pytest.approx(1.0, abs=1e-12)
    assert [k for k, _ in SCENE_KINDS] == list(PAPER_KINDS + WALK_KINDS) == list(SCENE_FUNCTIONS)
    kinds = [scene_recipe(0, i)[0] for i in range(4000)]
    walk = [k for k in kinds if k in WALK_KINDS]
    paper = [k for k in kinds if k in PAPER_KINDS]
    assert 0.46 <= len(walk) / len(kinds) <= 0.54
    assert 0.66 <= sum(k in REGULAR_KINDS for k in paper) / len(paper) <= 0.74
    assert set(kinds) == set(REGULAR_KINDS) | set(IRREGULAR_KINDS) | set(WALK_KINDS)
    assert {scene_for(0, i).family for i in range(40)} == {"regular", "irregular", "walk"}


def test_bad_scene_requests_name_the_field():
    with pytest.raises(QzError, match="scene.kind"):
        make_scene("lava", 0.5, 0)
    with pytest.raises(QzError, match="scene.difficulty"):
        make_scene("stairs", 1.5, 0)


# -- walk-like kinds (issue 37) -------------------------------------------------------------
def _at(heightmap, x, y):
    """Height of the cell holding (x, y), None off the scene (no interpolation across an edge)."""
    xmin, xmax, ymin, ymax = heightmap.bounds
    if not (xmin <= x <= xmax and ymin <= y <= ymax):
        return None
    ix, iy = heightmap.index(x, y)
    return float(heightmap.heights[iy, ix])


def _feature_cells(scene):
    """(x, y, distance from the start) of every cell off level ground."""
    hm = scene.heightmap
    gx, gy = np.meshgrid(hm.x_coords, hm.y_coords)
    off = hm.heights != 0.0
    return gx[off], gy[off], np.hypot(gx[off], gy[off])


@pytest.mark.parametrize("kind", WALK_KINDS)
def test_walk_kinds_are_deterministic_from_their_seed(kind):
    a, b, other = make_scene(kind, 0.6, 11), make_scene(kind, 0.6, 11), make_scene(kind, 0.6, 12)
    assert a.params == b.params and np.array_equal(a.heightmap.heights, b.heightmap.heights)
    assert not np.array_equal(a.heightmap.heights, other.heightmap.heights)


@pytest.mark.parametrize("kind", WALK_KINDS)
def test_walk_kinds_leave_the_start_standable_at_any_heading(kind):
    from qz_drake.robot.topology import get_topology
    from qz_drake.scene import check_standable

    for seed in range(25):
        for difficulty in (0.0, 0.5, 1.0):
            scene = make_scene(kind, difficulty, seed)
            _, _, distance = _feature_cells(scene)
            # Every foot of every topology at every heading, moved as trials move them.
            assert distance.size and distance.min() > FOOTPRINT_RADIUS, (seed, difficulty)
    for seed in range(5):
        hm = make_scene(kind, 1.0, seed).heightmap
        for topology in ("nominal", "split_up"):
            check_standable(hm, (0.0, 0.0), topology, "start")  # no box under the trunk
            footholds = get_topology(topology).footholds_B[:, :2]
            for yaw in np.radians(np.arange(0, 360, 45)):
                c, s = math.cos(yaw), math.sin(yaw)
                feet = footholds @ np.array([[c, s], [-s, c]])
                assert np.all(np.abs(hm.height(feet[:, 0], feet[:, 1])) < 0.02), (seed, topology, yaw)


def test_stair_flights_are_where_their_parameters_say():
    for seed in range(40):
        for difficulty in (0.3, 1.0):
            scene = make_scene("stair_flight", difficulty, seed)
            p, hm = scene.params, scene.heightmap
            along = np.array([math.cos(p["heading"]), math.sin(p["heading"])])
            left = np.array([-along[1], along[0]])

            # Walk the line through the start where it crosses the flight, else its centre line.
            line = 0.0 if p["placement"] == "across" else p["centre"]

            def at(u, v=None):
                x, y = u * along + (line if v is None else p["centre"] + v) * left
                return _at(hm, x, y)

            expected = [(p["near"] - 0.15, 0.0)]
            expected += [(p["near"] + (k + 0.5) * p["run"], (k + 1) * p["rise"]) for k in range(p["steps"])]
            top = p["near"] + p["steps"] * p["run"]
            if p["shape"] == "hill":
                expected += [(top + 0.5 * p["landing"], p["steps"] * p["rise"]),
                             (top + p["landing"] + 0.5 * p["run"], (p["steps"] - 1) * p["rise"]),
                             (top + p["landing"] + p["steps"] * p["run"] + 0.15, 0.0)]
            else:
                expected += [(top + 0.3, p["steps"] * p["rise"])]
            for u, height in expected:
                found = at(u)
                assert found is None or found == pytest.approx(height, abs=1e-9), (seed, p["shape"], u)
            # Nothing beyond the flight's sides.
            for side in (-1, 1):
                found = at(p["near"] + 0.5 * p["run"], side * (p["width"] / 2 + 0.15))
                assert found is None or found == 0.0
            assert abs(p["rise"]) == pytest.approx(np.interp(difficulty, (0, 0.5, 1), FIG9_RISE))
            assert p["steps"] in (2, 3) and 0.3 <= p["run"] <= 0.5


def test_stair_flight_headings_spread_over_every_direction():
    headings, shapes, across = [], [], 0
    for seed in range(400):
        scene = make_scene("stair_flight", 0.5, seed)
        p = scene.params
        headings.append(p["heading"])
        shapes.append(p["shape"])
        x, y, distance = _feature_cells(scene)
        nearest = int(np.argmin(distance))
        if p["placement"] == "across":
            across += 1
            # The start faces the flight's width: its nearest cell lies ahead along the heading,
            # at the first nose.
            seen = math.atan2(y[nearest], x[nearest])
            assert abs(math.remainder(seen - p["heading"], 2 * math.pi)) < math.radians(20), seed
            assert distance[nearest] == pytest.approx(p["near"], abs=0.08)
        else:
            # A flight beside the start: its near side passes 1-1.6 m away, from behind to ahead.
            assert distance[nearest] < 1.75, seed
    octants = np.bincount(((np.asarray(headings) + math.pi) // (math.pi / 4)).astype(int) % 8, minlength=8)
    assert octants.min() >= 30, octants  # 50 expected in each
    assert 0.62 <= across / 400 <= 0.78
    # Fig. 9's hills half the time, else steps up or down to a level beyond the scene.
    assert 0.42 <= shapes.count("hill") / 400 <= 0.58
    assert min(shapes.count("up"), shapes.count("down")) / 400 >= 0.17


@pytest.mark.parametrize("kind", WALK_KINDS)
def test_difficulty_raises_the_walk_features(kind):
    easy = [make_scene(kind, 0.0, seed) for seed in range(12)]
    hard = [make_scene(kind, 1.0, seed) for seed in range(12)]
    for e, h in zip(easy, hard):
        if "rise" in e.params:
            assert abs(h.params["rise"]) > abs(e.params["rise"]) and h.params["width"] > e.params["width"]
        if "max_height" in e.params:
            assert h.params["max_height"] > e.params["max_height"] and h.params["share"] > e.params["share"]
        if kind == "box_field":  # the same boxes first, then more and higher
            assert h.params["count"] >= e.params["count"]
            assert np.count_nonzero(h.heightmap.heights) > np.count_nonzero(e.heightmap.heights)
            assert h.heightmap.heights.max() > e.heightmap.heights.max()
        if kind == "pits":
            assert e.params["shape"] == h.params["shape"]
            assert h.params["count"] > e.params["count"] or h.params["width"] > e.params["width"]
            assert np.count_nonzero(h.heightmap.heights) > np.count_nonzero(e.heightmap.heights)
    if kind == "stairs_among_boxes":  # boxes beside the flight: more of them over the seeds
        boxes = [sum(s.params["count"] for s in scenes) for scenes in (easy, hard)]
        assert boxes[1] > boxes[0]


def test_box_fields_hold_fig9_boxes_around_a_clear_start():
    for seed in range(20):
        for difficulty in (0.0, 0.5, 1.0):
            scene = make_scene("box_field", difficulty, seed)
            p, heights = scene.params, scene.heightmap.heights
            level = np.interp(difficulty, (0, 0.5, 1), FIG9_BOX_SHARE)
            assert 0.75 * level <= p["share"] <= 1.25 * level
            boxes = heights[heights != 0.0]
            assert np.all(boxes >= p["min_height"]) and np.all(boxes <= p["max_height"]) and np.all(boxes > 0)
            # Boxes cover their share of the scene outside the start's disc (overlaps counted
            # twice, as Fig. 9 counts them; the last box may overshoot by one of 1 m x 1 m).
            open_area = (2 * SCENE_HALF_SIZE) ** 2 - math.pi
            covered = boxes.size * scene.heightmap.resolution**2
            assert 0.5 * p["share"] * open_area <= covered <= p["share"] * open_area + 1.0, (seed, difficulty)


def test_stairs_among_boxes_is_the_same_seeds_flight_with_boxes_beside_it():
    for seed in range(20):
        for difficulty in (0.2, 0.9):
            both = make_scene("stairs_among_boxes", difficulty, seed)
            flight = make_scene("stair_flight", difficulty, seed)
            assert {k: both.params[k] for k in flight.params} == flight.params
            on_flight = flight.heightmap.heights != 0.0
            assert np.array_equal(both.heightmap.heights[on_flight], flight.heightmap.heights[on_flight])
            boxes = both.heightmap.heights[~on_flight & (both.heightmap.heights != 0.0)]
            assert np.all(boxes >= both.params["min_height"]) and np.all(boxes <= both.params["max_height"])
            box_field_share = np.interp(difficulty, (0, 0.5, 1), FIG9_BOX_SHARE) * both.params["density"]
            assert both.params["share"] == pytest.approx(box_field_share / 2)


def test_pits_are_holes_or_a_trench_near_the_start():
    shapes = set()
    for seed in range(40):
        for difficulty in (0.0, 1.0):
            scene = make_scene("pits", difficulty, seed)
            p, hm = scene.params, scene.heightmap
            shapes.add(p["shape"])
            x, y, _ = _feature_cells(scene)
            assert np.all(hm.heights <= 0.0) and x.size
            if p["shape"] == "holes":
                assert 1 <= p["count"] <= 6
                assert np.all(np.maximum(np.abs(x), np.abs(y)) < PIT_REACH)
                assert hm.heights.min() >= -p["max_depth"] and hm.heights[hm.heights < 0].max() <= -0.15
            else:
                assert p["width"] == pytest.approx(0.15 + 0.3 * difficulty)
                along = np.array([math.cos(p["heading"]), math.sin(p["heading"])])
                left = np.array([-along[1], along[0]])
                inside = (p["near"] + p["width"] / 2) * along + p["centre"] * left
                before = (p["near"] - 0.1) * along + p["centre"] * left
                assert _at(hm, *inside) in (None, -p["depth"]) and _at(hm, *before) in (None, 0.0)
                assert 0.3 <= p["depth"] <= 0.6 and 2.4 <= p["length"] <= 3.2
    assert shapes == {"holes", "trench"}


def test_walk_kinds_use_the_fig9_worlds_features():
    from qz_drake.experiments import worlds

    levels = worlds.DIFFICULTIES
    assert FIG9_RISE == tuple(worlds._STAIRS[d][0] for d in levels)
    assert FIG9_HILL_WIDTH == tuple(worlds._STAIRS[d][1] for d in levels)
    assert FIG9_BOX_HEIGHT == tuple(worlds._OBSTACLES[d][0] for d in levels)
    assert FIG9_BOX_SHARE == tuple(worlds._OBSTACLES[d][1] for d in levels)
    assert (FIG9_RUN, FIG9_STEPS, FIG9_LANDING) == (worlds._RUN, worlds._STEPS, worlds._LANDING)
    # And the worlds' hills climb by that rise: the levels a stairs world holds.
    for level, rise in zip(levels, FIG9_RISE):
        heights = worlds.make_task("stairs", level, 0).heightmap.heights
        assert np.unique(heights) == pytest.approx([0.0, rise, 2 * rise])


def test_trial_scenes_are_disjoint_from_the_fig9_experiment_and_tuning_worlds():
    from qz_drake.experiments import worlds

    seeds = {scene_recipe(seed, i)[2] for seed in range(4) for i in range(500)}
    # Task seeds: the experiment's 0 to TASKS_PER_CELL - 1, the walks that check the model from
    # VALIDATION_SEED_START on, the tunings' from TUNING_SEED_START on, one per task.
    assert min(seeds) >= SCENE_SEED_START > worlds.TUNING_SEED_START + 10**6
    assert worlds.TASKS_PER_CELL <= worlds.VALIDATION_SEED_START < worlds.TUNING_SEED_START
    # The random streams too: a scene draws from default_rng(scene seed), a world from
    # default_rng([terrain, difficulty, task seed, 0xF19]); no scene's first draw is a world's.
    task_seeds = [*range(worlds.TASKS_PER_CELL), *range(worlds.VALIDATION_SEED_START, worlds.TUNING_SEED_START),
                  *range(worlds.TUNING_SEED_START, worlds.TUNING_SEED_START + 1000)]
    world_draws = {int(np.random.default_rng([t, d, s, 0xF19]).integers(2**63))
                   for t in range(len(worlds.TERRAINS)) for d in range(len(worlds.DIFFICULTIES)) for s in task_seeds}
    scene_draws = {int(np.random.default_rng(s).integers(2**63)) for s in seeds}
    assert len(world_draws) == 9 * len(task_seeds) and len(scene_draws) == len(seeds)
    assert not world_draws & scene_draws
