"""Episodes from the stances the planners' own walks stood in (issue 54: data from its own routes).

The capability episodes (qz_drake.capability.episodes) start on a scene's flat start, standing
in a topology with perturbed feet, and draw the planner's actions at random. A planner's walk
meets other starts: the stance the last mission left, on a step, beside a box, a few
centimetres off the footholds the map assumes. A *route episode* starts there: at a mission
start a Fig. 9 walk recorded (``record_missions``: the base pose and the feet the BLC planned
the mission from, its topology and its target), on that walk's world, and walks the planner's
own actions towards the mission's target (turns to face it, moves of one cell along the
nearest of the eight headings, turns to its heading: the route as the model's actions), then,
up to the episode's EPISODE_MISSIONS moves, actions drawn as an episode draws them. Each
mission is labelled as an episode's (walked, no plan, executed and failed; its own stretch
judged by the strict verdict), with the trials' BLC and its ladder.

Only walks on training worlds (worlds.seed_role "training": seeds from TRAINING_SEED_START)
are taken: the experiment's, the reserved, the validation and the tuning worlds are never
learned from. The records' ``scene`` is ROUTE_SCENE_BASE plus the world's place among the
collection's worlds (so the train/validation/test split keeps a world's starts together, apart
from every capability scene), ``scene_kind`` "fig9_<terrain>", ``difficulty`` 0, 0.5 or 1
(simple, medium, hard), ``scene_seed`` the world's seed.

A collection (:func:`collect_route_episodes`, ``qz capability collect-routes``) is stored,
resumed and trained on like an episode collection; its settings name the walks it drew its
starts from (their results files' digests), and a resume from other walks is refused.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import math
from pathlib import Path

import numpy as np

from qz_drake.errors import ConfigError, bad_value

# Scene ids of the route episodes' worlds: apart from every capability scene (0, 1, ... per
# collection, below a million).
ROUTE_SCENE_BASE = 1_000_000
# A recorded mission that moves the body less than this is a turn in place. [m]
TURN_IN_PLACE = 0.25
DIFFICULTY_VALUES = {"simple": 0.0, "medium": 0.5, "hard": 1.0}
PROTOCOL = "routes"
# Starts closer than this (same world, topology and target cell) are one start. [m], [rad]
SAME_START_XY, SAME_START_YAW = 0.02, math.radians(2.0)


@dataclasses.dataclass(frozen=True)
class RouteSpec:
    """One route episode: where a recorded walk's mission started and what it asked for."""

    seed: int  # the collection's seed: draws the actions after the route's own
    index: int
    scene: int  # ROUTE_SCENE_BASE + the world's place among the collection's worlds
    topology: str
    terrain: str
    difficulty: str
    world_seed: int
    scale: float
    start: tuple  # (x, y, yaw) of the base in the world [m, rad]
    feet: tuple  # six (x, y, z) feet in the world [m]
    target: tuple  # the mission's target (x, y, yaw)
    planner: str  # whose walk it came from

    @property
    def episode_id(self) -> str:
        return f"{self.seed}-r{self.index}"


def _results_files(runs) -> list[Path]:
    files = []
    for run in runs:
        path = Path(run)
        found = [path] if path.is_file() and path.name == "results.jsonl" else \
            sorted(path.rglob("results.jsonl")) if path.is_dir() else []
        if not found:
            raise bad_value("--walks", str(run), "holds no results.jsonl (a folder of qz experiment walks "
                                                 "with --record-missions)")
        files.extend(found)
    return files


def walks_digest(files) -> list[list[str]]:
    """[path, sha256 of its content (16 hex)] of each results file: what a collection's starts
    came from (its settings), so that a resume from other walks is refused."""
    return [[str(f), hashlib.sha256(Path(f).read_bytes()).hexdigest()[:16]] for f in files]


def route_specs(runs, seed: int) -> tuple[list[RouteSpec], list[list[str]]]:
    """(the route episodes of every mission start the walks under ``runs`` (folders, or their
    results.jsonl files) recorded, in file,
    task and mission order, the starts that repeat one dropped; the results files' digests).
    Raises QzError naming --walks for walks without mission records, on worlds that are not
    training worlds, or of another world scale."""
    from qz_drake.experiments.fig9 import read_settings
    from qz_drake.experiments.fig9.results import read_results
    from qz_drake.experiments.worlds import seed_role

    files = _results_files(runs)
    worlds: dict[tuple, int] = {}
    specs: list[RouteSpec] = []
    seen: list[tuple] = []
    for path in files:
        scale = float(read_settings(path.parent).get("scale", 1.0))
        for record in read_results(path.parent):
            if record.get("reason") == "error":
                continue
            role = seed_role(record["seed"])
            if role != "training":
                raise bad_value("--walks", str(path.parent),
                                f"walked world {record['key']} is a {role} world: only training worlds (seeds from "
                                f"worlds.TRAINING_SEED_START) are learned from")
            missions = record.get("mission_records")
            if not missions:
                raise bad_value("--walks", str(path.parent),
                                f"task {record['key']} kept no missions (walk with --record-missions)")
            world = (record["terrain"], record["difficulty"], int(record["seed"]), scale)
            scene = worlds.setdefault(world, ROUTE_SCENE_BASE + len(worlds))
            for m in missions:
                start = tuple(float(v) for v in m["start"])
                key = (world, m["topology"], start, tuple(float(v) for v in m["target"]))
                if any(_same_start(key, other) for other in seen):
                    continue
                seen.append(key)
                specs.append(RouteSpec(seed, len(specs), scene, m["topology"], *world, start,
                                       tuple(tuple(float(v) for v in foot) for foot in m["feet"]),
                                       tuple(float(v) for v in m["target"]), record["planner"]))
    return specs, walks_digest(files)


def _same_start(a, b) -> bool:
    """Whether two recorded starts are one: the same world, topology and target, and the base
    within SAME_START_XY and SAME_START_YAW (two planners' walks of a task stand up alike)."""
    if a[0] != b[0] or a[1] != b[1]:
        return False
    (xa, ya, ta), (xb, yb, tb) = a[2], b[2]
    return (math.hypot(xa - xb, ya - yb) < SAME_START_XY and abs(math.remainder(ta - tb, 2 * math.pi)) < SAME_START_YAW
            and math.hypot(a[3][0] - b[3][0], a[3][1] - b[3][1]) < SAME_START_XY)


@functools.lru_cache(maxsize=4)
def _world_map(terrain: str, difficulty: str, seed: int, scale: float):
    from qz_drake.experiments.worlds import make_task

    return make_task(terrain, difficulty, seed, scale).heightmap


def start_window(heightmap, x: float, y: float, half_size: float):
    """The map within ``half_size`` of (x, y), moved so that (x, y) is its (0, 0), and run on
    past the world's edge (capability.episodes.padded_scene_map): an episode's map."""
    from qz_drake.capability.episodes import padded_scene_map
    from qz_drake.terrain.heightmap import HeightMap

    window = heightmap.crop(x - half_size, x + half_size, y - half_size, y + half_size)
    moved = HeightMap(window.heights, window.resolution, (window.origin[0] - x, window.origin[1] - y),
                      window.materials, window.material_names)
    return padded_scene_map(moved, half_size)


def _turns(h: int, to: int) -> list[int]:
    """45 deg turns (+1 left, -1 right) from heading index ``h`` to ``to`` (shortest; left at 180)."""
    steps = (to - h) % 8
    return [1] * steps if steps <= 4 else [-1] * (8 - steps)


def _heading(yaw: float) -> int:
    """The nearest of the planner's eight headings to ``yaw`` (its index)."""
    from qz_drake.capability.patches import HEADING_STEP

    return int(round(yaw / HEADING_STEP)) % 8


def _scene(spec: RouteSpec, heightmap=None):
    """What a route episode's records say of its scene (capability.episodes._record): the world."""
    import types

    return types.SimpleNamespace(kind=f"fig9_{spec.terrain}", difficulty=DIFFICULTY_VALUES[spec.difficulty],
                                 seed=spec.world_seed, heightmap=heightmap)


def route_commands(spec: RouteSpec, half_size: float):
    """(start yaw [rad], foot offsets (6, 2) in the base frame from the topology's footholds,
    missions) of a route episode, in the frame moved to its start: the planner's own actions
    towards the recorded target first (turns to face it, moves of one cell, turns to its
    heading; at most EPISODE_MISSIONS moves and turns), then actions drawn as an episode draws
    them (capability.episodes.CommandDraw, from the collection's seed and the spec's index)."""
    from qz_drake.capability.episodes import EPISODE_MISSIONS, CommandDraw, Mission
    from qz_drake.capability.patches import HEADING_STEP, kind_of_heading, move_distance
    from qz_drake.robot.params import DEFAULT_PARAMS
    from qz_drake.robot.topology import get_topology

    sx, sy, yaw = spec.start
    c, s = math.cos(yaw), math.sin(yaw)
    feet = np.asarray(spec.feet, dtype=float)[:, :2] - [sx, sy]
    offsets = feet @ np.array([[c, -s], [s, c]]) - get_topology(spec.topology, DEFAULT_PARAMS).footholds_B[:, :2]
    h = _heading(yaw)
    x = y = 0.0
    topology = spec.topology
    missions: list = []

    def turn(step: int):
        nonlocal h
        h = (h + step) % 8
        missions.append(Mission("turn", 0 if step > 0 else 1, (x, y, h * HEADING_STEP), topology))

    tx, ty, tyaw = spec.target
    dx, dy = tx - sx, ty - sy
    distance = math.hypot(dx, dy)
    if distance >= TURN_IN_PLACE:
        bearing = _heading(math.atan2(dy, dx))
        for step in _turns(h, bearing):
            turn(step)
        kind = kind_of_heading(bearing)
        d = move_distance(kind)
        for _ in range(max(1, int(round(distance / d)))):
            x, y = x + d * math.cos(h * HEADING_STEP), y + d * math.sin(h * HEADING_STEP)
            missions.append(Mission(kind, -1, (x, y, h * HEADING_STEP), topology))
    for step in _turns(h, _heading(tyaw)):
        turn(step)
    if not missions:  # neither a move nor a whole turn: one turn towards the target's heading
        turn(1 if math.remainder(tyaw - yaw, 2 * math.pi) >= 0 else -1)
    missions = missions[:EPISODE_MISSIONS]
    x, y = missions[-1].target[0], missions[-1].target[1]
    h = _heading(missions[-1].target[2])
    draw = CommandDraw(np.random.default_rng([spec.seed, spec.index, 0x70E5]), half_size)
    while len(missions) < EPISODE_MISSIONS + sum(m.kind == "switch" for m in missions):
        switch = draw.switch(False, x, y, h, topology)
        if switch is not None:
            missions.append(switch)
            topology = switch.topology
        mission, h, _ = draw.move(x, y, h, topology)
        if mission is None:
            break
        missions.append(mission)
        x, y = mission.target[0], mission.target[1]
    return yaw, offsets, missions


def run_route_episode(spec: RouteSpec, config=None, criteria=None) -> list[dict]:
    """Walks a route episode (the module docstring) and returns its records, as
    capability.episodes.run_episode does for a scene's episode."""
    import time

    from qz_drake.capability.episodes import EPISODE_HALF_SIZE, walk_episode
    from qz_drake.capability.trials import TrialConfig

    clock = time.perf_counter()
    config = TrialConfig() if config is None else config
    heightmap = start_window(_world_map(spec.terrain, spec.difficulty, spec.world_seed, spec.scale),
                             spec.start[0], spec.start[1], EPISODE_HALF_SIZE)
    yaw, offsets, missions = route_commands(spec, EPISODE_HALF_SIZE)
    return walk_episode(spec, _scene(spec, heightmap), yaw, offsets, missions, config, criteria, clock)


def execute_route_episode(spec: RouteSpec, config) -> list[dict]:
    """What a worker runs for a route episode: its records, one per mission."""
    from qz_drake.capability.collect import start_work

    start_work(spec)
    return run_route_episode(spec, config)


def crashed_route_episode(spec: RouteSpec, message: str, config) -> list[dict]:
    """The record of a route episode whose worker died (status "error", excluded from training)."""
    from qz_drake.capability.episodes import Mission, _record

    record = _record(spec, _scene(spec), 0, Mission("turn", 0, spec.target, spec.topology))
    record.update(status="error", error=message[:400])
    return [record]


def collect_route_episodes(out, runs, *, seed: int = 0, config=None, workers: int = 1, shard_size: int = 100,
                           progress: bool = True, command: str = "", limit: int | None = None,
                           log_every: float = 0.0, ray_address: str | None = None):
    """Collects (or resumes) the route episodes of the walks under ``runs`` into the dataset
    folder ``out`` (capability.collect.collect_units); returns its CollectionSummary."""
    from qz_drake.capability.collect import collect_units
    from qz_drake.capability.dataset import settings_dict
    from qz_drake.capability.trials import TrialConfig

    config = TrialConfig() if config is None else config
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise bad_value("--seed", seed, "must be a whole number >= 0 (it seeds numpy's generators)")
    specs, walks = route_specs(runs, seed)
    if not specs:
        raise ConfigError(f"--walks: the walks under {', '.join(map(str, runs))} recorded no mission start")
    settings = settings_dict(config)
    settings.update(protocol=PROTOCOL, walks=walks)
    return collect_units(out, specs, seed=seed, settings=settings, config=config, function=execute_route_episode,
                         crashed=crashed_route_episode, unit="episodes", workers=workers, ray_address=ray_address,
                         shard_size=shard_size, progress=progress, command=command, limit=limit,
                         log_every=log_every)


def recertify_hooks():
    """capability.collect.RecertifyHooks of a route-episode dataset: its specs made again from
    the walks its settings name, refused when a results file is gone or changed."""
    from qz_drake.capability.collect import RecertifyHooks

    def specs(settings, seed):
        walks = settings.get("walks") or []
        files = [Path(path) for path, _ in walks]
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise bad_value("dataset.settings.walks", missing[0], "is gone: the route episodes' starts came from it")
        if walks_digest(files) != [list(w) for w in walks]:
            raise bad_value("dataset.settings.walks", [w[0] for w in walks],
                            "changed since the collection (their digests differ): not the starts it was collected from")
        made, _ = route_specs(files, seed)
        return {s.index: s for s in made}

    return RecertifyHooks(PROTOCOL, ("walks",), specs, execute_route_episode, crashed_route_episode)
