"""Scenario configuration: typed dataclasses with a YAML form (pydrake.common.yaml).

A scenario file holds only what differs from the defaults below; ``save_scenario`` writes it
back that way. Every field a user can mistype is checked with a message naming its dotted
path (``scenario.terrain.knd: unknown field ...``) before Drake's typed loader runs.
"""


import dataclasses
import math
import re
import typing
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed

from qz_drake.errors import ConfigError, bad_value


@dataclasses.dataclass
class TerrainConfig:
    # A generator of qz_drake.terrain (flat, slope, stairs, step, gap, pits, waves, rough,
    # obstacles, long_range, material_floor), "grid_map" (the packaged grid_map image) or "file".
    kind: str = "flat"
    # Generator parameters in SI units, e.g. {rise: 0.1, count: 2} for stairs (a seed here seeds
    # the terrain instead of random_seed); for grid_map and for a picture file: resolution [m]
    # (cell size), min_height [m] and max_height [m] (the heights of pixel values 0 and full scale).
    params: dict[str, float] = dataclasses.field(default_factory=dict)
    # Heightmap file when kind is "file": a .npz (HeightMap.save_npz), a map-server .yaml with
    # its image, or a picture (.png, ...) with its scale in params; centred on the origin. A
    # relative path is relative to the scenario file's folder.
    file: str = ""
    # Contact geometry: "auto", "boxes" (point contact) or "mesh" (hydroelastic).
    contact: str = "auto"
    # Ground material where the map has no per-cell labels: concrete, wood or foam.
    material: str = "concrete"
    # Part of the map simulated [xmin, xmax, ymin, ymax] in metres; empty: the controller's
    # reach (standing: 2 m around the start). Contact geometry cost grows with the area.
    region: list[float] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class RobotConfig:
    # Body topology, one of qz_drake.robot.topology.TOPOLOGY_NAMES.
    topology: str = "nominal"
    # Extra mass on the trunk (paper 002: up to 20 kg). [kg]
    payload_kg: float = 0.0
    # Initial base position on the map. [m]
    initial_xy: list[float] = dataclasses.field(default_factory=lambda: [0.0, 0.0])
    # Initial heading. [rad]
    initial_yaw: float = 0.0
    # Moves (dx, dy) of the six feet from the topology's nominal footholds at the start, base
    # frame (the stance a previous mission left); empty: nominal. [m]
    initial_foot_offsets: list[list[float]] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class SimulationConfig:
    # Simulated time. [s]
    duration: float = 5.0
    # Discrete plant step; 2 ms keeps the explicit joint PD stable with the reflected inertia. [s]
    time_step: float = 0.002
    # Drake's discrete contact approximation: lagged (fast, default), similar, sap or tamsi.
    discrete_contact_approximation: str = "lagged"


@dataclasses.dataclass
class StationConfig:
    # "torque": the station takes joint torques (the controllers compute Eq. 7);
    # "position": it takes joint position commands, held by the drives' own PD (the plant's
    # implicit PD actuators), as the paper drives the real robot; joint_torque is then a
    # feedforward added to it.
    control_mode: str = "torque"
    # Drive stiffness in position mode. [N*m/rad]
    position_kp: float = 3000.0
    # Drive damping in position mode. [N*m*s/rad]
    position_kd: float = 40.0


@dataclasses.dataclass
class Waypoint:
    # Position on the map. [m]
    x: float = 0.0
    y: float = 0.0
    # Heading on arrival. [rad]
    yaw: float = 0.0
    # Topology to walk this leg of the route in.
    topology: str = "nominal"


@dataclasses.dataclass(frozen=True)
class MissionTiming:
    """How a BLC or tripod mission is timed: distance / speed, rounded to whole tripod cycles
    (two phases). The one place of these defaults: the walking scenario's controller, the
    capability trials (part of the dataset's fingerprint) and the Fig. 9 experiment keep the two
    numbers as flat fields of their own settings (their YAML and JSON keys) defaulting to these,
    and hand the BLC system and the tripod plan a MissionTiming (their ``timing``)."""

    # Average walking speed of a mission. [m/s]
    speed: float = 0.25
    # One tripod swing (= stance) phase. [s]
    phase_duration: float = 0.4


@dataclasses.dataclass(frozen=True)
class WalkDrives:
    """How the BLC's walks drive the joints, and the plant's step (issue 53): "position", Eq. 7's
    PD in the drives (the plant's implicit PD actuators on the tracker's q_des and v_des, with
    ControllerConfig's kp and kd), the controller adding its compensation and force feedforward
    at the tracker's rate, so that no Python runs at the plant's step. The one place of these
    defaults: the capability trials (part of a dataset's fingerprint) and Fig. 9's walks keep the
    two as flat fields of their own settings (their JSON keys and the commands' options)
    defaulting to these, and the demo's scenario is built with them (``drive_station``). Generic
    scenarios keep SimulationConfig's and StationConfig's own defaults (the explicit PD at 2 ms)
    unless their file names others. 8 ms is the longest step measured whose largest errors stay
    those of the controller's PD at 2 ms (BENCHMARKS "walks and episodes, the drives' PD"): on
    40 stored episodes 141 of 142 labels kept at 0.63x the time, joint errors to 3.9 deg (2 ms:
    4.1) and final errors to 4.1 cm (3.9); at 10 ms 139 of 141, but joint errors to 6.0 deg and
    final errors to 5.1 cm."""

    # StationConfig.control_mode of the walks.
    control_mode: str = "position"
    # The plant's step of the walks. [s]
    time_step: float = 0.008


def drive_station(control_mode: str, kp: float, kd: float) -> StationConfig:
    """The station of a walk driven in ``control_mode``: in position mode the drives' PD with
    Eq. 7's gains ``kp`` and ``kd`` (the walk controller's; the trials' are the same)."""
    if control_mode == "torque":
        return StationConfig()
    return StationConfig(control_mode="position", position_kp=kp, position_kd=kd)


@dataclasses.dataclass
class ControllerConfig:
    # "stand": joint PD (paper 000 Eq. 7) holding the topology's standing pose;
    # "walk": missions along `route`, planned by `planner`, tracked by IK + joint PD.
    kind: str = "stand"
    # Mission planner for "walk": "tripod" (kinematic alternating tripod plan), "blc" (the
    # trajectory optimisation of paper 000, solved per mission from the measured state, along
    # the route) or "capplanner" (paper 000's whole CapPlanner: the learned capability model and
    # value iteration choose the missions and topologies to the route's last waypoint, the
    # goal; the BLC solves each).
    planner: str = "tripod"
    # capplanner only: the capability model folder; empty: the one shipped in the package.
    capability_model: str = ""
    # capplanner only: settings of its MDP other than the defaults, by name
    # (qz_drake.planning.capability_mdp.CapabilityMdpConfig), e.g. {failure_reward: -200}.
    capability_mdp: dict[str, float] = dataclasses.field(default_factory=dict)
    # Waypoints of the route for "walk", from the start.
    route: list[Waypoint] = dataclasses.field(default_factory=list)
    # Longest local mission along the route. [m]
    mission_length: float = 1.0
    # Average walking speed of a mission (and of a trot). [m/s]
    speed: float = MissionTiming.speed
    # One tripod swing (= stance) phase. [s]
    phase_duration: float = MissionTiming.phase_duration
    # BLC planner only: ask for the next mission this long before the current plan ends, so
    # that the BLC solves it from the plan's expected end state while the robot walks (paper
    # 000); 0: at the end, from the measured state. [s]
    plan_ahead: float = 0.0
    # Joint stiffness. [N*m/rad]
    kp: float = 1500.0
    # Joint damping. [N*m*s/rad]
    kd: float = 30.0

    @property
    def timing(self) -> MissionTiming:
        return MissionTiming(self.speed, self.phase_duration)


@dataclasses.dataclass
class SuccessCriteria:
    """Bounds of the strict verdict (qz_drake.verdict), shared by scenarios and capability
    trials. The defaults were chosen from the walks of scenarios/*.yaml (see
    benchmarks/BENCHMARKS.md, "verdict"): each passes them with a margin, and the failures
    they catch were seen in real runs."""

    # Largest allowed deviation of the base height from the planned / nominal height
    # (standing scenarios). [m]
    max_base_height_error: float = 0.02
    # Largest allowed trunk tilt. [deg]
    max_tilt_deg: float = 30.0
    # Largest allowed final distance to the goal (walking scenarios). [m]
    max_final_xy_error: float = 0.15
    # Largest allowed final heading error (walking scenarios). [deg]
    max_final_yaw_error_deg: float = 10.0
    # Largest allowed joint tracking error at any instant. [deg]
    max_joint_error_deg: float = 25.0
    # Largest allowed horizontal drift of a foot during one contact. [m]
    max_foot_slip_m: float = 0.05
    # A leg link pressed on the terrain (or on another leg) harder than this is a contact. [N]
    leg_contact_force: float = 5.0


@dataclasses.dataclass
class Scenario:
    # A short name, used in file names and reports.
    name: str = "stand_flat"
    # What the scenario shows and how success is judged, in a sentence or two.
    description: str = ""
    # Seeds every random process of the scenario (terrain generators, noise).
    random_seed: int = 0
    terrain: TerrainConfig = dataclasses.field(default_factory=TerrainConfig)
    robot: RobotConfig = dataclasses.field(default_factory=RobotConfig)
    simulation: SimulationConfig = dataclasses.field(default_factory=SimulationConfig)
    station: StationConfig = dataclasses.field(default_factory=StationConfig)
    controller: ControllerConfig = dataclasses.field(default_factory=ControllerConfig)
    success: SuccessCriteria = dataclasses.field(default_factory=SuccessCriteria)


DISCRETE_APPROXIMATIONS = ("lagged", "similar", "sap", "tamsi")
# Longest simulated time of one run. Its recording grows by about 100 kB per simulated second
# (measured: stand_flat, 2.5 MB at 2 s, 3.3 MB at 10 s), so 1200 s is a 120 MB page a browser
# still opens; the longest shipped scenario (capplanner_long_range) allows 300 s. [s]
MAX_SIMULATED_TIME = 1200.0
# Most plant steps of one run: 1200 s at the default 2 ms step.
MAX_PLANT_STEPS = 600_000
CONTROLLER_KINDS = ("stand", "walk")
CONTROL_MODES = ("torque", "position")
PLANNERS = ("tripod", "blc", "capplanner")


class _YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads exponents without a dot or a sign (1e9, 1.0e9) as
    numbers, as YAML 1.2 and Drake's typed loader do; YAML 1.1 takes them for text, and a
    scenario's ``duration: 1.0e9`` was refused as "expected a number"."""

    def construct_mapping(self, node, deep=False):
        # YAML keeps the last of two equal keys without a word: a second `simulation:` section
        # silently replaced the first. (Keys a merge key `<<` brings in may be overridden.)
        if isinstance(node, yaml.MappingNode):
            first_line = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                    continue
                key, line = self.construct_object(key_node), key_node.start_mark.line + 1
                if key in first_line:
                    where = f"twice on line {line}" if first_line[key] == line else \
                        f"on lines {first_line[key]} and {line}"
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {key!r} {where}; give each key once")
                first_line[key] = line
        return super().construct_mapping(node, deep=deep)


_YamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9][0-9_]*)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))


def yaml_load(text: str):
    """``yaml.safe_load`` with YAML 1.2's exponent forms read as numbers (see _YamlLoader)."""
    return yaml.load(text, Loader=_YamlLoader)


# The files most often passed where a text file was meant, by their first bytes.
_BINARY_SIGNATURES = ((b"\x89PNG\r\n\x1a\n", "a PNG picture"), (b"\xff\xd8\xff", "a JPEG picture"),
                      (b"PK\x03\x04", "a zip archive (a .npz heightmap?)"), (b"\x93NUMPY", "a numpy array"),
                      (b"%PDF", "a PDF document"), (b"\x7fELF", "a program"))


def read_text_file(path, field: str, expected: str) -> str:
    """The UTF-8 text of the file ``path``; a missing file, a folder or a binary file (a picture,
    random bytes) is a ConfigError naming ``field`` and the path, ``expected`` saying what was
    wanted (e.g. "a scenario .yaml file")."""
    path = Path(path)
    if path.is_dir():
        raise bad_value(field, str(path), f"is a folder; expected {expected}")
    if not path.is_file():
        raise bad_value(field, str(path), "no such file")
    data = path.read_bytes()
    kind = next((name for signature, name in _BINARY_SIGNATURES if data.startswith(signature)), None)
    if kind is not None:
        raise bad_value(field, str(path), f"is {kind}, not text; expected {expected}")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise bad_value(field, str(path), f"is not UTF-8 text (byte 0x{data[e.start]:02x} at offset {e.start}); "
                                          f"expected {expected}") from None


def _check_fields(schema, data, path: str) -> None:
    """Raises ConfigError for a key that no dataclass field of ``schema`` has."""
    if not dataclasses.is_dataclass(schema) or data is None:
        return
    if not isinstance(data, dict):
        raise bad_value(path, data, "expected a mapping of fields")
    hints = typing.get_type_hints(schema)
    fields = {f.name for f in dataclasses.fields(schema)}
    for key, value in data.items():
        if key not in fields:
            raise bad_value(f"{path}.{key}", value,
                            f"unknown field (valid: {', '.join(sorted(fields))})")
        _check_value(hints[key], value, f"{path}.{key}")


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_value(hint, value, path: str) -> None:
    """Raises ConfigError when ``value`` cannot be read as ``hint`` (a dataclass, float, int, str,
    bool, list[...] or dict[str, float]): Drake's typed loader would say only, e.g.,
    "'float' object is not iterable", without the field."""
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        _check_fields(hint, value, path)
    elif origin is list:
        if not isinstance(value, list):
            raise bad_value(path, value, "expected a list, e.g. [1.0, 2.0]")
        (item,) = typing.get_args(hint)
        for k, entry in enumerate(value):
            _check_value(item, entry, f"{path}[{k}]")
    elif origin is dict:
        if not isinstance(value, dict):
            raise bad_value(path, value, "expected a mapping, e.g. {rise: 0.1}")
        _, item = typing.get_args(hint)
        for key, entry in value.items():
            _check_value(item, entry, f"{path}.{key}")
    elif hint is float:
        if not _is_number(value):
            raise bad_value(path, value, "expected a number")
    elif hint is int:
        if not (isinstance(value, int) and not isinstance(value, bool)):
            raise bad_value(path, value, "expected a whole number")
    elif hint is bool:
        if not isinstance(value, bool):
            raise bad_value(path, value, "expected true or false")
    elif hint is str:
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise bad_value(path, value, "expected a text")


def _positive(path: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise bad_value(path, value, "must be a finite positive number")


def check_simulated_time(field: str, value) -> float:
    """``value`` as the simulated time of one run: finite, positive and at most
    MAX_SIMULATED_TIME; errors name ``field`` and the value."""
    _positive(field, value)
    if value > MAX_SIMULATED_TIME:
        raise bad_value(field, value, f"longer than the limit of {MAX_SIMULATED_TIME:g} s of simulated time for one "
                                      f"run (its recording grows by about 100 kB per second)")
    return float(value)


def validate_scenario(scenario: Scenario) -> Scenario:
    """Checks values that the YAML types cannot; returns the scenario."""
    from qz_drake.robot.topology import TOPOLOGY_NAMES
    from qz_drake.terrain import TERRAIN_KINDS, get_material
    from qz_drake.terrain.drake_geometry import CONTACT_KINDS

    t = scenario.terrain
    kinds = tuple(TERRAIN_KINDS) + ("grid_map", "file")
    if t.kind not in kinds:
        raise bad_value("scenario.terrain.kind", t.kind, f"unknown terrain kind (valid: {', '.join(kinds)})")
    if t.kind == "file" and not t.file:
        raise bad_value("scenario.terrain.file", t.file, "required when terrain.kind is 'file'")
    for key, value in t.params.items():
        if not math.isfinite(value):
            raise bad_value(f"scenario.terrain.params.{key}", value, "must be finite")
    if "resolution" in t.params:
        _positive("scenario.terrain.params.resolution", t.params["resolution"])
    if t.region and (len(t.region) != 4 or not all(math.isfinite(v) for v in t.region)
                     or t.region[1] <= t.region[0] or t.region[3] <= t.region[2]):
        raise bad_value("scenario.terrain.region", t.region, "expected [xmin, xmax, ymin, ymax] with min < max")
    if t.contact not in CONTACT_KINDS:
        raise bad_value("scenario.terrain.contact", t.contact, f"expected one of {', '.join(CONTACT_KINDS)}")
    try:
        get_material(t.material)
    except Exception as e:  # re-raise with the scenario's field path
        raise bad_value("scenario.terrain.material", t.material, str(e)) from None
    r = scenario.robot
    if r.topology not in TOPOLOGY_NAMES:
        raise bad_value("scenario.robot.topology", r.topology, f"expected one of {', '.join(TOPOLOGY_NAMES)}")
    if not (0.0 <= r.payload_kg <= 20.0):
        raise bad_value("scenario.robot.payload_kg", r.payload_kg, "must be within [0, 20] kg")
    if len(r.initial_xy) != 2 or not all(math.isfinite(v) for v in r.initial_xy):
        raise bad_value("scenario.robot.initial_xy", r.initial_xy, "expected two finite numbers")
    s = scenario.simulation
    check_simulated_time("scenario.simulation.duration", s.duration)
    _positive("scenario.simulation.time_step", s.time_step)
    if s.duration / s.time_step > MAX_PLANT_STEPS:
        raise bad_value("scenario.simulation.time_step", s.time_step,
                        f"{s.duration:g} s in steps of {s.time_step:g} s is {s.duration / s.time_step:.3g} plant "
                        f"steps; at most {MAX_PLANT_STEPS} in one run")
    if s.discrete_contact_approximation not in DISCRETE_APPROXIMATIONS:
        raise bad_value("scenario.simulation.discrete_contact_approximation",
                        s.discrete_contact_approximation,
                        f"expected one of {', '.join(DISCRETE_APPROXIMATIONS)}")
    st = scenario.station
    if st.control_mode not in CONTROL_MODES:
        raise bad_value("scenario.station.control_mode", st.control_mode, f"expected one of {', '.join(CONTROL_MODES)}")
    if st.control_mode == "position" and s.discrete_contact_approximation == "tamsi":
        raise bad_value("scenario.simulation.discrete_contact_approximation", "tamsi",
                        "position mode needs the plant's PD actuators, which TAMSI ignores")
    _positive("scenario.station.position_kp", st.position_kp)
    _positive("scenario.station.position_kd", st.position_kd)
    for name in ("max_base_height_error", "max_tilt_deg", "max_final_xy_error",
                 "max_final_yaw_error_deg", "max_joint_error_deg", "max_foot_slip_m",
                 "leg_contact_force"):
        _positive(f"scenario.success.{name}", getattr(scenario.success, name))
    c = scenario.controller
    if c.kind not in CONTROLLER_KINDS:
        raise bad_value("scenario.controller.kind", c.kind, f"expected one of {', '.join(CONTROLLER_KINDS)}")
    if c.planner not in PLANNERS:
        raise bad_value("scenario.controller.planner", c.planner, f"expected one of {', '.join(PLANNERS)}")
    if c.kind == "walk" and not c.route:
        raise bad_value("scenario.controller.route", c.route, "a walking scenario needs at least one waypoint")
    for k, w in enumerate(c.route):
        if w.topology not in TOPOLOGY_NAMES:
            raise bad_value(f"scenario.controller.route[{k}].topology", w.topology,
                            f"expected one of {', '.join(TOPOLOGY_NAMES)}")
        if not all(math.isfinite(v) for v in (w.x, w.y, w.yaw)):
            raise bad_value(f"scenario.controller.route[{k}]", [w.x, w.y, w.yaw], "must be finite")
    _positive("scenario.controller.mission_length", c.mission_length)
    _positive("scenario.controller.speed", c.speed)
    _positive("scenario.controller.phase_duration", c.phase_duration)
    if not (math.isfinite(c.plan_ahead) and c.plan_ahead >= 0):
        raise bad_value("scenario.controller.plan_ahead", c.plan_ahead, "must be a non-negative number of seconds")
    for key, value in c.capability_mdp.items():
        if not math.isfinite(value):
            raise bad_value(f"scenario.controller.capability_mdp.{key}", value, "must be finite")
    _positive("scenario.controller.kp", c.kp)
    _positive("scenario.controller.kd", c.kd)
    return scenario


def load_scenario_text(text: str, source: str = "<string>") -> Scenario:
    """The validated Scenario of a scenario's YAML ``text``; ``source`` names it in errors."""
    if not isinstance(text, str):
        raise bad_value("text", text if text is None else type(text).__name__,
                        "expected the text of a scenario YAML file (load_scenario reads a file)")
    try:
        raw = yaml_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{source}: not valid YAML ({str(e).splitlines()[0]})") from None
    if raw is None:
        # An empty file would silently run the default scenario (standing on flat ground).
        raise bad_value("scenario", source, "holds no fields; an empty file would run the default scenario (see scenarios/*.yaml)")
    _check_fields(Scenario, raw, "scenario")
    try:
        scenario = yaml_load_typed(schema=Scenario, data=text)
    except (RuntimeError, ValueError, TypeError) as e:
        raise ConfigError(f"{source}: {e}") from None
    return validate_scenario(scenario)


def resolve_paths(scenario: Scenario, folder) -> Scenario:
    """Makes the scenario's relative file paths (terrain.file) relative to ``folder``, the
    scenario file's folder, as a map-server YAML's image is relative to the YAML."""
    file = scenario.terrain.file
    if file and not Path(file).expanduser().is_absolute():
        scenario.terrain.file = str(Path(folder) / file)
    elif file:
        scenario.terrain.file = str(Path(file).expanduser())
    return scenario


def load_scenario(path) -> Scenario:
    """Loads and validates a scenario YAML file; relative paths in it are relative to its folder."""
    path = Path(path)
    text = read_text_file(path, "scenario", "a scenario .yaml file (see scenarios/)")
    return resolve_paths(load_scenario_text(text, str(path)), path.parent)


def save_scenario(scenario: Scenario, path) -> None:
    """Writes only the fields that differ from the defaults."""
    Path(path).write_text(yaml_dump_typed(scenario, defaults=Scenario()))


def parse_key_values(items: list[str] | None, field: str = "--param") -> dict[str, float]:
    """Parses ``k=v`` pairs into floats, naming the bad item on error."""
    out: dict[str, float] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{field} = {item!r}: expected KEY=VALUE")
        try:
            out[key] = float(value)
        except ValueError:
            raise ConfigError(f"{field} {key} = {value!r}: not a number") from None
    return out


def feet_on_ground(p_BF, xy, yaw: float) -> np.ndarray:
    """(n, 2) world (x, y) of feet at base-frame positions ``p_BF`` (n, >= 2) for a base at
    ``xy`` turned by ``yaw``. [m]"""
    c, s = math.cos(yaw), math.sin(yaw)
    p = np.asarray(p_BF, dtype=float)[:, :2]
    return np.asarray(xy, dtype=float)[:2] + p @ np.array([[c, s], [-s, c]])


def check_feet_on_map(heightmap, feet_xy, *, map_field: str, map_value, position_field: str, position_value,
                      robot: str = "Qingzhui") -> None:
    """Refuses a start with a foot off the map, where heights are the border's, clamped: a map
    narrower than the robot (a 3 x 997 pixel picture) let it "stand" with four feet on nothing.

    A map smaller than the feet's spread is blamed on the map (``map_field``), any other foot off
    the map on the position (``position_field``)."""
    feet_xy = np.asarray(feet_xy, dtype=float)
    inside = np.asarray(heightmap.contains(feet_xy[:, 0], feet_xy[:, 1]))
    if inside.all():
        return
    xmin, xmax, ymin, ymax = heightmap.bounds
    spread = feet_xy.max(axis=0) - feet_xy.min(axis=0)
    if xmax - xmin < spread[0] or ymax - ymin < spread[1]:
        raise bad_value(map_field, map_value,
                        f"the map is {xmax - xmin:.2f} m x {ymax - ymin:.2f} m, smaller than {robot}'s footprint "
                        f"({spread[0]:.2f} m x {spread[1]:.2f} m between the feet)")
    k = int(np.argmin(inside))
    raise bad_value(position_field, position_value,
                    f"{robot}'s foot {k} would stand at ({feet_xy[k, 0]:.2f}, {feet_xy[k, 1]:.2f}), off the map "
                    f"(x in [{xmin:g}, {xmax:g}], y in [{ymin:g}, {ymax:g}] m)")
