"""The scene a station is built on, shared by both backends (sim and LCM hardware) and by the
commands that check their input before any work: the heightmap a scenario's terrain section
names, the part of it simulated, the standing start on it (leg IK per topology), and the checks
that the robot can stand where a scenario or command puts it.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from pydrake.math import RollPitchYaw

from qz_drake.config import Scenario, TerrainConfig, check_feet_on_map, feet_on_ground
from qz_drake.errors import ConfigError, KinematicsError, QzError, TerrainError, bad_value
from qz_drake.robot import kinematics
from qz_drake.robot.params import DEFAULT_PARAMS, LEG_NAMES, NUM_LEGS, QingzhuiParams
from qz_drake.robot.topology import Topology, get_topology
from qz_drake.state_layout import BASE_Z, make_state
from qz_drake.terrain import HeightMap, grid_map_terrain, make_terrain

GRAVITY = 9.81


def load_heightmap_file(path, field: str, value, **scale) -> HeightMap:
    """``HeightMap.load(path, **scale)``; an error about the file itself (not a heightmap, too
    few pixels) names ``field`` and ``value``, the file as the user gave it, in place of the
    loader's own field."""
    try:
        return HeightMap.load(path, **scale)
    except TerrainError as e:
        for loader_field in ("heightmap.file", "heightmap.image"):
            prefix = f"{loader_field} = {str(path)!r}: "
            if str(e).startswith(prefix):
                raise bad_value(field, value, str(e)[len(prefix):], TerrainError) from None
        raise


def make_heightmap(config: TerrainConfig, seed: int = 0):
    """The HeightMap a scenario's terrain section describes."""
    if config.kind == "file":
        path = Path(config.file)
        if not path.is_file():
            raise bad_value("scenario.terrain.file", config.file,
                            "no such file (a relative path is relative to the scenario file's folder)")
        scale = {"resolution", "min_height", "max_height"}
        for key in config.params:
            if key not in scale:
                raise bad_value(f"scenario.terrain.params.{key}", config.params[key],
                                f"unknown parameter of a heightmap file (valid: {', '.join(sorted(scale))})")
        if path.suffix.lower() in HeightMap.IMAGE_SUFFIXES:
            for key in ("resolution", "max_height"):
                if key not in config.params:
                    raise bad_value(f"scenario.terrain.params.{key}", None,
                                    f"required with a picture file ({path.name}): its cell size and the "
                                    f"height of a full-scale pixel, e.g. params: {{resolution: 0.05, "
                                    f"min_height: 0.0, max_height: 0.4}}")
            return load_heightmap_file(path, "scenario.terrain.file", config.file, **config.params)
        if config.params:
            key = sorted(config.params)[0]
            raise bad_value(f"scenario.terrain.params.{key}", config.params[key],
                            f"a {path.suffix} file carries its own scale; give params only with an image")
        return load_heightmap_file(path, "scenario.terrain.file", config.file)
    if config.kind == "grid_map":
        allowed = {"resolution", "min_height", "max_height"}
        for key in config.params:
            if key not in allowed:
                raise bad_value(f"scenario.terrain.params.{key}", config.params[key],
                                f"unknown grid_map parameter (valid: {', '.join(sorted(allowed))})")
        return grid_map_terrain(**config.params)
    # A seed among the generator's parameters (--terrain-param seed=4711) takes the place of `seed`.
    params = dict(config.params)
    return make_terrain(config.kind, seed=params.pop("seed", seed), **params)


def standing_state(heightmap, topology: Topology, xy=(0.0, 0.0), yaw: float = 0.0,
                   params: QingzhuiParams = DEFAULT_PARAMS, foot_offsets=None) -> np.ndarray:
    """A station state standing on the terrain: base level at the nominal height above the mean
    ground under the feet, each foot placed on the ground by leg IK (topology's bends).

    foot_offsets: (6, 2) moves of the feet from their nominal footholds in the base frame
    (the stance a previous mission may leave), or None. [m]"""
    R = RollPitchYaw(0.0, 0.0, yaw).ToRotationMatrix().matrix()
    p_B = topology.footholds_B.copy()
    if foot_offsets is not None and len(foot_offsets):
        offsets = np.asarray(foot_offsets, dtype=float)
        if offsets.shape != (NUM_LEGS, 2) or not np.all(np.isfinite(offsets)):
            raise bad_value("scenario.robot.initial_foot_offsets", np.asarray(foot_offsets).tolist(),
                            "expected six finite (dx, dy) pairs", ConfigError)
        p_B[:, :2] += offsets
    feet_xy = np.asarray(xy, dtype=float) + (p_B[:, :2] @ R[:2, :2].T)
    ground = heightmap.height(feet_xy[:, 0], feet_xy[:, 1])
    base_z = float(np.mean(ground)) + params.standing_height
    q = np.zeros((NUM_LEGS, 3))
    for i in range(NUM_LEGS):
        p_WF = np.array([feet_xy[i, 0], feet_xy[i, 1], ground[i] + params.foot_radius])
        p_BF = R.T @ (p_WF - np.array([xy[0], xy[1], base_z]))
        q[i], ok = kinematics.leg_inverse_kinematics(i, p_BF, topology.bends[i], params)
        if not ok:
            offset = ground[i] - float(np.mean(ground))
            raise bad_value("scenario.robot.initial_xy", [float(v) for v in xy],
                            f"the ground under leg {LEG_NAMES[i]} at ({feet_xy[i, 0]:.2f}, {feet_xy[i, 1]:.2f}) "
                            f"is {abs(offset):.2f} m {'above' if offset > 0 else 'below'} the mean under the "
                            f"six feet, out of the leg's reach for a standing pose", ConfigError)
    return make_state([xy[0], xy[1], base_z], [0.0, 0.0, yaw], q.reshape(-1))


def check_standable(heightmap, xy, topology: str, field: str) -> None:
    """Raises QzError naming ``field`` when the robot cannot stand at xy in the topology."""
    xmin, xmax, ymin, ymax = heightmap.bounds
    if not (xmin <= xy[0] <= xmax and ymin <= xy[1] <= ymax):
        raise bad_value(field, f"{xy[0]:g},{xy[1]:g}", f"off the map (x in [{xmin:g}, {xmax:g}], "
                                                      f"y in [{ymin:g}, {ymax:g}])")
    try:
        x0 = standing_state(heightmap, get_topology(topology), xy, 0.0)
    except QzError:
        raise bad_value(field, f"{xy[0]:g},{xy[1]:g}",
                        f"the robot cannot stand there in {topology} (a foot out of reach)") from None
    # The trunk must clear the ground under it (any heading: the disc the trunk sweeps).
    lx, ly, lz = DEFAULT_PARAMS.trunk_size
    radius = 0.5 * float(np.hypot(lx, ly))
    g = np.arange(-radius, radius + 1e-9, 0.05)
    gx, gy = np.meshgrid(g, g)
    inside = np.hypot(gx, gy) <= radius
    ground = heightmap.height(xy[0] + gx[inside], xy[1] + gy[inside])
    if float(ground.max()) > float(x0[BASE_Z]) - 0.5 * lz - 0.02:
        raise bad_value(field, f"{xy[0]:g},{xy[1]:g}",
                        f"the robot cannot stand there in {topology}: ground {ground.max():.2f} m under "
                        f"the trunk (inside an obstacle?)")


# Half-width of the simulated terrain around a standing robot's start. [m]
STANDING_REGION_HALF_WIDTH = 2.0


def default_region(scenario: Scenario) -> list[float]:
    """The part of the map a scenario's controller can reach: the start and every waypoint of
    its route, with a margin of STANDING_REGION_HALF_WIDTH."""
    xs = [scenario.robot.initial_xy[0]] + [w.x for w in scenario.controller.route]
    ys = [scenario.robot.initial_xy[1]] + [w.y for w in scenario.controller.route]
    r = STANDING_REGION_HALF_WIDTH
    return [min(xs) - r, max(xs) + r, min(ys) - r, max(ys) + r]


def crop_to_region(heightmap, region):
    """The part of ``heightmap`` inside ``region`` [xmin, xmax, ymin, ymax] (all of it when the
    region covers it); a region off the map is a ConfigError."""
    xmin, xmax, ymin, ymax = heightmap.bounds
    if region[0] <= xmin and region[1] >= xmax and region[2] <= ymin and region[3] >= ymax:
        return heightmap
    try:
        return heightmap.crop(*region)
    except ConfigError:
        raise
    except Exception as e:
        raise bad_value("scenario.terrain.region", list(region), f"does not overlap the map ({e})") from None


@dataclasses.dataclass
class StationInfo:
    """What a caller of make_station may need to know about what was built."""

    heightmap: object
    contact_representation: str
    params: QingzhuiParams
    topology: Topology
    initial_state: np.ndarray


# The generator parameter that sets the height of the terrain's features, by terrain kind: a
# start that Qingzhui cannot stand on is blamed on it (the terrain is what the user changed).
_HEIGHT_PARAMS = {"stairs": "rise", "step": "height", "gap": "depth", "pits": "depth", "waves": "amplitude",
                  "rough": "amplitude", "obstacles": "max_height", "slope": "angle_deg",
                  "grid_map": "max_height", "file": "max_height"}


def check_against_map(scenario: Scenario, heightmap) -> None:
    """Checks what only the map can decide: the start and every waypoint lie on it, and the
    robot can stand at the start. Raises ConfigError naming the field and its value.

    A waypoint off the map would be simulated and reported only as a goal missed by tens of
    metres; a start the legs cannot stand on would be blamed on the start position although
    the terrain's parameters made it."""
    xmin, xmax, ymin, ymax = heightmap.bounds
    where = f"off the map (x in [{xmin:g}, {xmax:g}], y in [{ymin:g}, {ymax:g}] m)"
    r = scenario.robot
    if not bool(heightmap.contains(r.initial_xy[0], r.initial_xy[1])):
        raise bad_value("scenario.robot.initial_xy", list(r.initial_xy), where)
    for k, w in enumerate(scenario.controller.route):
        if not bool(heightmap.contains(w.x, w.y)):
            raise bad_value(f"scenario.controller.route[{k}]", {"x": w.x, "y": w.y}, where)
    # The nominal stance: initial_foot_offsets move the feet by centimetres, and standing_state
    # checks their shape.
    t = scenario.terrain
    check_feet_on_map(heightmap, feet_on_ground(get_topology(r.topology).footholds_B, r.initial_xy, r.initial_yaw),
                      map_field="scenario.terrain.file" if t.kind == "file" else "scenario.terrain.params",
                      map_value=t.file if t.kind == "file" else dict(t.params),
                      position_field="scenario.robot.initial_xy", position_value=list(r.initial_xy))
    params = dataclasses.replace(DEFAULT_PARAMS, payload_mass=r.payload_kg)
    try:
        standing_state(heightmap, get_topology(r.topology, params), r.initial_xy, r.initial_yaw, params,
                       foot_offsets=r.initial_foot_offsets or None)
    except (ConfigError, KinematicsError) as e:
        if "initial_foot_offsets" in str(e):
            raise
        name = _HEIGHT_PARAMS.get(t.kind)
        why = str(e).split(": ", 1)[-1]
        if name in t.params:
            raise bad_value(f"scenario.terrain.params.{name}", t.params[name],
                            f"Qingzhui cannot stand at scenario.robot.initial_xy = {list(r.initial_xy)} on this "
                            f"terrain: {why}") from None
        if t.kind == "file":
            raise bad_value("scenario.robot.initial_xy", list(r.initial_xy),
                            f"Qingzhui cannot stand there on scenario.terrain.file = {t.file!r}: {why}") from None
        raise
    except QzError:
        raise
