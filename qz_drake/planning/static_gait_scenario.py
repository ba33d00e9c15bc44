"""Static-gait scenarios (paper 003, sections 3-4): search a gait on a terrain, walk it in Drake.

A scenario file names the terrain, the start and heading, how many steps to take and how far
to look ahead, and the search's and the simulation's settings; it holds only what differs
from the defaults below. The terrain is any kind a robot scenario accepts
(``qz_drake.config.TerrainConfig``) or ``cuboids``, the structured terrain of section 4.2
(:func:`~qz_drake.planning.static_gait.cuboid_terrain`: cuboids of random heights whose edges
are invalid footholds), seeded by ``random_seed``. ``run_static_gait`` writes the searched
states (JSON and npz), the meshcat recording and the metrics.
"""

import dataclasses
import json
import math
import time
import typing
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed

from qz_drake.config import MAX_PLANT_STEPS, MAX_SIMULATED_TIME, TerrainConfig, read_text_file, yaml_load
from qz_drake.errors import ConfigError, bad_value
from qz_drake.planning.static_gait import (LEGS, MAX_DEPTH, MAX_STEPS, GaitSearchResult, StaticGaitConfig,
                                           cuboid_terrain, search_gait)
from qz_drake.planning.static_gait import _check_config as check_gait_config
from qz_drake.planning.static_gait_sim import StaticGaitSimConfig, simulate_static_gait
from qz_drake.planning.static_gait_sim import _check_config as check_sim_config

# Parameters of the ``cuboids`` terrain kind and their defaults (section 4.2). [m]
CUBOID_PARAMS = {"size_x": 1.2, "size_y": 0.6, "block_x": 0.1, "block_y": 0.1, "max_height": 0.025,
                 "resolution": 0.005, "origin_x": -0.3, "origin_y": -0.3}


def _default_terrain() -> TerrainConfig:
    # No default params: Drake's YAML loader merges maps, so they would leak into other kinds.
    return TerrainConfig(kind="cuboids")


@dataclasses.dataclass
class StaticGaitScenario:
    # Name written into the outputs.
    name: str = "static_gait_cuboids"
    # One line about the scenario.
    description: str = ""
    # Seed of random terrains (the cuboids' heights).
    random_seed: int = 0
    # The terrain: a robot scenario's terrain kind, or "cuboids" with CUBOID_PARAMS.
    terrain: TerrainConfig = dataclasses.field(default_factory=_default_terrain)
    # Body centre at the start, world frame. [m]
    start_xy: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0])
    # Walking direction. [rad]
    heading: float = 0.0
    # Swings to search and walk; a gait cycle is four.
    steps: int = 8
    # Steps searched ahead before one is committed (section 3.3.2); 1 is greedy.
    depth: int = 4
    # The gait search's robot geometry, candidates and checks.
    gait: StaticGaitConfig = dataclasses.field(default_factory=StaticGaitConfig)
    # Timing, gains and success thresholds of the walk in Drake.
    simulation: StaticGaitSimConfig = dataclasses.field(default_factory=StaticGaitSimConfig)


def _check_fields(schema, data, path: str) -> None:
    """ConfigError for a key no dataclass field of ``schema`` has (Drake's loader would only
    say that a key is unknown, not where)."""
    if not dataclasses.is_dataclass(schema) or data is None:
        return
    if not isinstance(data, dict):
        raise bad_value(path, data, "expected a mapping of fields")
    hints = typing.get_type_hints(schema)
    for key, value in data.items():
        if key not in hints:
            raise bad_value(f"{path}.{key}", value, f"unknown field (valid: {', '.join(sorted(hints))})")
        _check_fields(hints[key], value, f"{path}.{key}")


def validate_static_gait_scenario(scenario: StaticGaitScenario) -> StaticGaitScenario:
    from qz_drake.terrain import TERRAIN_KINDS

    kinds = ("cuboids",) + tuple(TERRAIN_KINDS) + ("grid_map", "file")
    t = scenario.terrain
    if t.kind not in kinds:
        raise bad_value("scenario.terrain.kind", t.kind, f"unknown terrain kind (valid: {', '.join(kinds)})")
    for key, value in t.params.items():
        if not math.isfinite(value):
            raise bad_value(f"scenario.terrain.params.{key}", value, "must be finite")
        if t.kind == "cuboids" and key not in CUBOID_PARAMS:
            raise bad_value(f"scenario.terrain.params.{key}", value,
                            f"unknown cuboids parameter (valid: {', '.join(CUBOID_PARAMS)})")
    if scenario.random_seed < 0:
        raise bad_value("scenario.random_seed", scenario.random_seed, "must be >= 0 (it seeds numpy's generator)")
    if len(scenario.start_xy) != 2 or not all(math.isfinite(v) for v in scenario.start_xy):
        raise bad_value("scenario.start_xy", scenario.start_xy, "expected two finite numbers [m]")
    if not math.isfinite(scenario.heading):
        raise bad_value("scenario.heading", scenario.heading, "must be finite")
    if not 1 <= scenario.depth <= MAX_DEPTH:
        raise bad_value("scenario.depth", scenario.depth, f"must be within [1, {MAX_DEPTH}] steps ahead")
    # The search's and the walk's own checks, before anything runs.
    check_gait_config(scenario.gait)
    check_sim_config(scenario.simulation)
    check_walk_length(scenario)
    return scenario


def check_walk_length(scenario: StaticGaitScenario, steps_field: str = "scenario.steps") -> None:
    """Refuses a walk longer than a robot scenario may simulate (MAX_SIMULATED_TIME, and
    MAX_PLANT_STEPS plant steps, IK samples or monitor checks): its swings (named
    ``steps_field``) or a step too fine are named with the most the run allows."""
    s = scenario.simulation
    if scenario.steps < 1:
        raise bad_value(steps_field, scenario.steps, "must be >= 1")
    per_swing = s.shift_duration + s.swing_duration
    standing = s.settle_duration + s.hold_duration
    walk = standing + scenario.steps * per_swing
    default_step = StaticGaitSimConfig().time_step
    for name in ("time_step", "sample_period", "monitor_period"):
        period = getattr(s, name)
        if period < default_step and walk / period > MAX_PLANT_STEPS:
            raise bad_value(f"scenario.simulation.{name}", period,
                            f"a walk of {walk:.4g} s in steps of {period:g} s is {walk / period:.3g} steps; "
                            f"at most {MAX_PLANT_STEPS} in one run")
    longest = min(MAX_SIMULATED_TIME, MAX_PLANT_STEPS * s.time_step)
    if walk > longest or scenario.steps > MAX_STEPS:
        most = min(MAX_STEPS, int((longest - standing) // per_swing))
        raise bad_value(steps_field, scenario.steps,
                        f"{scenario.steps} swings of {per_swing:g} s are a walk of {walk:.4g} s; at most {most} "
                        f"swings ({longest:g} s simulated, at most {MAX_PLANT_STEPS} plant steps of "
                        f"{s.time_step:g} s) in one run")


def load_static_gait_scenario(path) -> StaticGaitScenario:
    """Loads and validates a static-gait scenario YAML file."""
    path = Path(path)
    text = read_text_file(path, "scenario", "a static-gait scenario .yaml file (see scenarios/static_gait/)")
    try:
        raw = yaml_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    _check_fields(StaticGaitScenario, raw if raw is not None else {}, "scenario")
    try:
        scenario = yaml_load_typed(schema=StaticGaitScenario, data=text if raw else "{}")
    except (RuntimeError, ValueError, TypeError, AssertionError) as e:
        raise ConfigError(f"{path}: {e}") from None
    return validate_static_gait_scenario(scenario)


def save_static_gait_scenario(scenario: StaticGaitScenario, path) -> None:
    """Writes only the fields that differ from the defaults."""
    Path(path).write_text(yaml_dump_typed(scenario, defaults=StaticGaitScenario()))


def make_static_gait_heightmap(scenario: StaticGaitScenario):
    """The scenario's terrain as a HeightMap (cropped to terrain.region when that is set)."""
    from qz_drake.scene import make_heightmap

    t = scenario.terrain
    if t.kind == "cuboids":
        p = {**CUBOID_PARAMS, **t.params}
        heightmap = cuboid_terrain(scenario.random_seed, size=(p["size_x"], p["size_y"]),
                                   block=(p["block_x"], p["block_y"]), max_height=p["max_height"],
                                   resolution=p["resolution"], origin=(p["origin_x"], p["origin_y"]))
    else:
        heightmap = make_heightmap(t, scenario.random_seed)
    if t.region:
        if len(t.region) != 4:
            raise bad_value("scenario.terrain.region", t.region, "expected [xmin, xmax, ymin, ymax]")
        heightmap = heightmap.crop(*t.region)
    xmin, xmax, ymin, ymax = heightmap.bounds
    x, y = scenario.start_xy
    if not (xmin <= x <= xmax and ymin <= y <= ymax):
        raise bad_value("scenario.start_xy", list(scenario.start_xy),
                        f"off the map (x in [{xmin:g}, {xmax:g}], y in [{ymin:g}, {ymax:g}])")
    return heightmap


def states_to_dict(result: GaitSearchResult) -> dict:
    """The searched gait as JSON-ready data."""
    return {
        "success": bool(result.success),
        "reason": result.reason,
        "nodes_expanded": int(result.nodes_expanded),
        "legs": list(LEGS),
        "start": {"feet": np.asarray(result.start_feet).tolist(), "p_WB": np.asarray(result.start_p_WB).tolist(),
                  "rpy": np.asarray(result.start_rpy).tolist()},
        "states": [{"step": s.step, "leg": s.leg, "feet": s.feet.tolist(), "p_WB": s.p_WB.tolist(),
                    "rpy": s.rpy.tolist(), "choice": list(s.choice)} for s in result.states],
    }


def save_states_npz(result: GaitSearchResult, path) -> Path:
    """Feet (K, 4, 3), body positions (K, 3), rpy (K, 3), swing legs and choices (K, 4)."""
    states = result.states
    np.savez_compressed(
        path, feet=np.array([s.feet for s in states]).reshape(-1, 4, 3),
        p_WB=np.array([s.p_WB for s in states]).reshape(-1, 3), rpy=np.array([s.rpy for s in states]).reshape(-1, 3),
        leg=np.array([s.leg for s in states], dtype="U2"), choice=np.array([s.choice for s in states]).reshape(-1, 4),
        start_feet=np.asarray(result.start_feet), start_p_WB=np.asarray(result.start_p_WB),
        start_rpy=np.asarray(result.start_rpy), legs=np.array(LEGS))
    return Path(path)


def run_static_gait(scenario: StaticGaitScenario, out_dir, *, meshcat=None, progress: bool = False) -> dict:
    """Searches the scenario's gait, walks it in Drake, writes ``states.json``, ``states.npz``,
    ``static_gait.png``, ``recording.html`` and ``metrics.json`` under ``out_dir``.

    Returns:
        the metrics: ``success`` (the search found all steps and the walk reached the last
        state), ``search`` (success, reason, nodes, time) and ``walk`` (the simulation's metrics).
    """
    from qz_drake.viz.costmap_plots import plot_static_gait

    validate_static_gait_scenario(scenario)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    heightmap = make_static_gait_heightmap(scenario)
    start = time.perf_counter()
    result = search_gait(heightmap, scenario.start_xy, scenario.heading, scenario.steps, scenario.depth,
                         scenario.gait)
    search_time = time.perf_counter() - start
    (out / "states.json").write_text(json.dumps(states_to_dict(result), indent=1))
    save_states_npz(result, out / "states.npz")
    plot_static_gait(heightmap, result, out / "static_gait.png", title=f"{scenario.name} (depth {scenario.depth})")
    walk_metrics = {"success": False, "reason": "no state to walk"}
    files = {"states_json": str(out / "states.json"), "states_npz": str(out / "states.npz"),
             "picture": str(out / "static_gait.png")}
    if result.states:
        if meshcat is None:
            from pydrake.geometry import Meshcat

            meshcat = Meshcat()
        walk = simulate_static_gait(heightmap, result, scenario.simulation, meshcat=meshcat,
                                    recording_path=out / "recording.html", params=_robot_params(scenario),
                                    progress=progress)
        walk_metrics = walk.metrics
        if walk.recording is not None:
            files["recording"] = str(walk.recording)
    metrics = {
        "scenario": scenario.name,
        "success": bool(result.success and walk_metrics["success"]),
        "steps": scenario.steps,
        "depth": scenario.depth,
        "search": {"success": bool(result.success), "reason": result.reason, "states": len(result.states),
                   "nodes_expanded": int(result.nodes_expanded), "time_s": search_time},
        "walk": walk_metrics,
        "files": files,
        "scenario_yaml": yaml_dump_typed(scenario, defaults=StaticGaitScenario()),
    }
    (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    return metrics


def _robot_params(scenario: StaticGaitScenario):
    """The simulated robot with the search's geometry, so both reason about the same legs."""
    from qz_drake.robot.quadruped import DEFAULT_QUADRUPED

    return dataclasses.replace(DEFAULT_QUADRUPED, geometry=scenario.gait.geometry,
                               foot_radius=scenario.gait.foot_radius)
