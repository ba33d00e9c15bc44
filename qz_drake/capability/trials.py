"""Capability trials (paper 000 II-E.1, III-B): one BLC mission executed by the robot in Drake.

A trial is a pure function of a small spec: the collection's seed, the trial's index, and from
them the scene, the heading, the start feet, the topology and the kind (``orthogonal``: 1 m
forward to the next cell centre; ``diagonal``: 1.41 m forward; ``turn``: 45 deg in place, left
or right). It builds the scene, stands the robot at the start cell's centre with its feet
moved around the topology's nominal stance (the state a previous mission leaves), and walks
the mission exactly as ``qz simulate`` walks a BLC scenario: TrajectoryOptimizationBLC ->
InverseKinematicsTracker -> joint PD (Eq. 7) -> the station, judged by the strict verdict
(qz_drake.verdict). The record holds the outcome and its reason, whether the BLC alone solved
it, the solver's time and iterations, the final errors, and the network inputs of paper 000
Fig. 4 (qz_drake.capability.patches).

Indices: trial ``index`` = ((scene * headings_per_scene + h) * 6 + topology) * 3 + kind, so
every (scene, heading, start feet) is tried in all six topologies and three kinds (paired
samples: the topology is the only difference), and choosing a subset of topologies or kinds
does not renumber the others.
"""

from __future__ import annotations

import dataclasses
import math
import time
import traceback

import numpy as np

from qz_drake.capability.patches import (HEADING_STEP, KINDS, feet_in_heading_frame,
                                         ground_reference, move_distance, sample_patches)
from qz_drake.config import MissionTiming, WalkDrives, drive_station
from qz_drake.errors import QzError
from qz_drake.robot.topology import TOPOLOGY_NAMES

# Terrain simulated around the start and the target. [m]
TRIAL_REGION_MARGIN = 1.6
# Number of heading samples (paper 000: 72 = 360 / 5 per scene); a trial's heading is one of
# them, drawn from its seed.
HEADING_SAMPLES = 72


@dataclasses.dataclass(frozen=True)
class TrialConfig:
    """How trials are run; part of the dataset's fingerprint. Each subsystem reads only its
    part: the mission timing goes to the BLC system, the bounds to the verdict."""

    # Heading samples per scene; each is tried in every topology and kind.
    headings_per_scene: int = 1
    # Largest move of a start foot from its nominal foothold, along x and y (inside the
    # kinematic box's 0.12-0.15 m). [m]
    foot_offset: float = 0.06
    # Mission speed and tripod phase, as the walking scenarios' defaults. [m/s], [s]
    speed: float = MissionTiming.speed
    phase_duration: float = MissionTiming.phase_duration
    # Joint PD gains (paper 000 Eq. 7). [N*m/rad], [N*m*s/rad]
    kp: float = 1500.0
    kd: float = 30.0
    # Simulated time after the mission's planned end before the verdict. [s]
    settle_after: float = 0.5
    # The BLC's budget per mission. Paper 000 III-A gives it 5 s of wall time; a wall-time
    # limit would make the labels depend on the machine's load (on this 2-core machine with
    # two workers and other processes, 79 of 97 probe trials hit it), so trials count Ipopt
    # iterations instead: 30 was 5 s at the 0.17-0.24 s per iteration that 1-1.5 m missions
    # over the Fig. 5 stairs took with SPRAL (benchmarks/BENCHMARKS.md, "blc"). With MUMPS a
    # trial's mission takes 0.035 (turn), 0.096 (orthogonal) and 0.135 s (diagonal) per
    # iteration, so 5 s is 40-140 iterations; but given the real 5 s limit instead (one
    # process beside one other), none of 42 trials that had failed at 30 iterations (14 per
    # kind) walked: 29 ran out of the 5 s, 13 stopped at local infeasibility (BENCHMARKS
    # "capability", session 28). 30 stays: the labels are those of the 5 s limit, at less
    # cost. The wall-time limit is a backstop against a hung solve only: generous, since
    # under heavy load (6 processes on 2 cores) 30 iterations took up to 34 s. [iterations], [s]
    blc_max_iterations: int = 30
    blc_time_limit: float = 120.0
    # Where the feet stand when each mission ends (BlcParameters.terminal_stance): "free", as
    # the BLC leaves them; "canonical", the target pose's canonical stance (trajopt/stance.py,
    # issue 54). A dataset is labelled by one of them.
    blc_terminal_stance: str = "free"
    # The BLC ladder a refused mission is solved again on before it counts as not planned
    # (TrajectoryOptimizationBLC's ``ladder``, qz_drake.systems.blc_plan.parse_ladder; e.g.
    # "cycles+1,split,split+1,cycles+2", the tuned walks'): labels of the BLC the planners walk
    # with. "": the first solve only (every dataset before issue 54's). Kept in its canonical
    # form (rungs comma-separated, no spaces).
    blc_ladder: str = ""
    # How the joints are driven (StationConfig.control_mode) and the plant's step, as the walks
    # (config.WalkDrives, the default). "position": the drives run Eq. 7's PD on the tracker's
    # q_des and v_des (the plant's implicit PD actuators, the same kp and kd), the controller
    # adds the compensation and force feedforward at the tracker's rate, and no Python runs at
    # the plant's step. "torque": the controller computes Eq. 7 (kp, kd above) at every plant
    # step, which must then be at most 2 ms (3 ms measured: slips and missed targets; every
    # dataset before issue 53's defaults). A dataset is labelled by one of them. [s]
    control_mode: str = WalkDrives.control_mode
    time_step: float = WalkDrives.time_step

    def __post_init__(self):
        from qz_drake.config import CONTROL_MODES
        from qz_drake.errors import bad_value

        from qz_drake.trajopt.parameters import TERMINAL_STANCES

        from qz_drake.systems.blc_plan import parse_ladder

        if not isinstance(self.blc_ladder, str):
            raise bad_value("trials.blc_ladder", self.blc_ladder, "expected a comma-separated string of rungs")
        object.__setattr__(self, "blc_ladder", ",".join(parse_ladder(self.blc_ladder, "trials.blc_ladder")))
        if self.blc_terminal_stance not in TERMINAL_STANCES:
            raise bad_value("trials.blc_terminal_stance", self.blc_terminal_stance,
                            f"expected one of {', '.join(TERMINAL_STANCES)}")
        if self.control_mode not in CONTROL_MODES:
            raise bad_value("trials.control_mode", self.control_mode, f"expected one of {', '.join(CONTROL_MODES)}")
        if not (isinstance(self.time_step, (int, float)) and 0 < self.time_step <= MAX_TRIAL_STEP):
            raise bad_value("trials.time_step", self.time_step, f"expected a step in (0, {MAX_TRIAL_STEP:g}] s")
        if self.control_mode == "torque" and self.time_step > MAX_EXPLICIT_PD_STEP:
            raise bad_value("trials.time_step", self.time_step,
                            f"the explicit joint PD (control_mode torque) needs steps of at most "
                            f"{MAX_EXPLICIT_PD_STEP:g} s; use control_mode position for longer ones")

    @property
    def ladder_allowance(self) -> float:
        """Simulated time each mission gets beyond its own for the ladder's rungs (a rung's plan
        is longer: tripod cycles added, or two halves each with its stands); 0 without a
        ladder, so that such trials are simulated as before. A walk stops once its missions are
        done, so the allowance costs nothing where no rung was needed. [s]"""
        return LADDER_ALLOWANCE if self.blc_ladder else 0.0

    def station_and_simulation(self, duration: float):
        """(StationConfig, SimulationConfig) of a trial's or episode's scenario lasting
        ``duration`` simulated seconds."""
        from qz_drake.config import SimulationConfig

        return (drive_station(self.control_mode, self.kp, self.kd),
                SimulationConfig(duration=duration, time_step=self.time_step))


# What a dataset was labelled with where its manifest's settings do not name a TrialConfig
# field (it was collected before the field existed): the values of that time, not today's
# defaults. Every dataset before issue 53's defaults drove the joints by the controller's PD at
# 2 ms; before issue 54 none had a ladder or a canonical end stance.
SETTINGS_BEFORE_THEY_EXISTED = {"control_mode": "torque", "time_step": 0.002, "blc_ladder": "",
                                "blc_terminal_stance": "free"}


def stored_trial_config(settings: dict, field: str = "dataset.settings") -> TrialConfig:
    """The TrialConfig a dataset's manifest ``settings`` (TrialConfig's fields only) name, with
    SETTINGS_BEFORE_THEY_EXISTED where they do not name a field; a field this code does not know
    is a QzError naming ``field``."""
    from qz_drake.errors import bad_value

    try:
        return TrialConfig(**{**SETTINGS_BEFORE_THEY_EXISTED, **settings})
    except TypeError as e:
        raise bad_value(field, settings, f"not this code's TrialConfig ({e})") from None


# Simulated time a mission may need beyond its own on the BLC ladder's longest rungs: split+N
# is two halves, each with its stands, N tripod cycles longer. [s]
LADDER_ALLOWANCE = 6.0
# Longest plant step a trial may take, and the longest the explicit joint PD stays stable at. [s]
MAX_TRIAL_STEP = 0.01
MAX_EXPLICIT_PD_STEP = 0.002


@dataclasses.dataclass(frozen=True)
class TrialSpec:
    """Everything a trial depends on (small: it travels to worker processes or Ray tasks)."""

    seed: int
    index: int
    scene: int
    heading_sample: int
    topology: str
    kind: str

    @property
    def trial_id(self) -> str:
        return f"{self.seed}-{self.index}"


def trial_index(scene: int, heading_sample: int, topology: str, kind: str,
                headings_per_scene: int) -> int:
    return ((scene * headings_per_scene + heading_sample) * len(TOPOLOGY_NAMES)
            + TOPOLOGY_NAMES.index(topology)) * len(KINDS) + KINDS.index(kind)


def trial_specs(seed: int, scenes: int, *, topologies=TOPOLOGY_NAMES, kinds=KINDS,
                headings_per_scene: int = 1) -> list[TrialSpec]:
    """The specs of a collection of ``scenes`` scenes, in index order."""
    specs = []
    for scene in range(scenes):
        for h in range(headings_per_scene):
            for topology in TOPOLOGY_NAMES:
                if topology not in topologies:
                    continue
                for kind in KINDS:
                    if kind in kinds:
                        specs.append(TrialSpec(seed, trial_index(scene, h, topology, kind, headings_per_scene),
                                               scene, h, topology, kind))
    return specs


def start_of(spec: TrialSpec, config: TrialConfig) -> tuple[float, np.ndarray, int]:
    """(heading [rad], foot offsets (6, 2) [m], turn direction d) of a spec's (scene, heading
    sample): shared by its six topologies and three kinds."""
    rng = np.random.default_rng([spec.seed, spec.scene, spec.heading_sample, 0x7A1])
    heading = float(rng.integers(0, HEADING_SAMPLES)) * 2 * math.pi / HEADING_SAMPLES
    offsets = rng.uniform(-config.foot_offset, config.foot_offset, (6, 2))
    return heading, offsets, int(rng.integers(0, 2))


def mission_target(kind: str, heading: float, direction: int) -> tuple[float, float, float]:
    """The mission's target (x, y, yaw) from the start (0, 0) facing ``heading``."""
    if kind == "turn":
        return 0.0, 0.0, heading + (HEADING_STEP if direction == 0 else -HEADING_STEP)
    d = move_distance(kind)
    return d * math.cos(heading), d * math.sin(heading), heading


def trial_scenario(spec: TrialSpec, config: TrialConfig, criteria=None):
    """The walking scenario of a trial (the scene's map is passed to the station apart)."""
    from qz_drake.config import (ControllerConfig, RobotConfig, Scenario,
                                 SuccessCriteria, TerrainConfig, Waypoint)

    heading, offsets, direction = start_of(spec, config)
    x, y, yaw = mission_target(spec.kind, heading, direction)
    # Simulate the ground the robot can reach on the way (its feet stay within about 1 m of
    # the base), not the whole scene: contact geometry costs grow with the area.
    r = TRIAL_REGION_MARGIN
    region = [min(0.0, x) - r, max(0.0, x) + r, min(0.0, y) - r, max(0.0, y) + r]
    # A mission is at most 2 tripod cycles longer than distance / speed (blc_plan).
    station, simulation = config.station_and_simulation(move_distance(spec.kind) / config.speed + 4.0
                                                         + config.ladder_allowance)
    return Scenario(
        name=f"trial_{spec.trial_id}",
        description="capability trial",
        terrain=TerrainConfig(kind="flat", region=region),
        robot=RobotConfig(topology=spec.topology, initial_xy=[0.0, 0.0], initial_yaw=heading,
                          initial_foot_offsets=offsets.tolist()),
        simulation=simulation,
        station=station,
        controller=ControllerConfig(kind="walk", planner="blc",
                                    route=[Waypoint(x=x, y=y, yaw=yaw, topology=spec.topology)],
                                    mission_length=2.0, speed=config.speed,
                                    phase_duration=config.phase_duration, kp=config.kp, kd=config.kd),
        success=criteria or SuccessCriteria(),
    ), direction


# Scalar fields of a record and their numpy dtypes, in the order shards store them.
RECORD_FIELDS: dict[str, str] = {
    "index": "i8", "scene": "i8", "heading_sample": "i8", "scene_kind": "U24", "difficulty": "f8",
    "scene_seed": "i8", "topology": "U16", "kind": "U16", "heading": "f8", "direction": "i1",
    "status": "U8", "success": "?", "reason": "U16", "message": "U200", "blc_success": "?",
    "blc_reason": "U200", "blc_iterations": "i8", "final_xy_error_m": "f8",
    "final_yaw_error_deg": "f8", "max_tilt_deg": "f8", "max_joint_error_deg": "f8",
    "max_foot_slip_m": "f8", "max_leg_link_force_n": "f8", "sim_time_s": "f8", "error": "U400",
}
# Array fields: the network inputs (paper 000 Fig. 4) and the start foot offsets.
ARRAY_FIELDS: dict[str, tuple[tuple[int, ...], str]] = {
    "patch": ((20, 20), "f4"), "feet": ((6, 3), "f4"), "foot_offsets": ((6, 2), "f8"),
}
# Measured wall times: machine measurements, not trial outcomes (left out when two datasets
# are compared array for array).
TIME_FIELDS: tuple[str, ...] = ("time_build_s", "time_solve_s", "time_sim_s", "time_total_s")


def _error_record(base: dict, message: str, status: str = "error") -> dict:
    base.update(status=status, success=False, reason="", message="", blc_success=False,
                blc_reason="", error=message[-400:])
    return base


def blank_record() -> dict:
    """A record with every field of the shards, each zero (or empty) of its dtype."""
    record = {name: np.zeros((), dtype=dt).item() for name, dt in RECORD_FIELDS.items()}
    record.update({name: np.zeros(shape, dtype=dt) for name, (shape, dt) in ARRAY_FIELDS.items()})
    record.update({name: 0.0 for name in TIME_FIELDS})
    return record


def base_record(spec: TrialSpec, config: TrialConfig, scene=None) -> dict:
    """A trial's record before it runs: its identity, scene and start, outcome fields zero."""
    from qz_drake.capability.scenes import scene_for

    scene = scene or scene_for(spec.seed, spec.scene)
    heading, offsets, direction = start_of(spec, config)
    record = blank_record()
    record.update(index=spec.index, scene=spec.scene, heading_sample=spec.heading_sample,
                  scene_kind=scene.kind, difficulty=scene.difficulty, scene_seed=scene.seed,
                  topology=spec.topology, kind=spec.kind, heading=heading,
                  direction=direction if spec.kind == "turn" else -1, foot_offsets=offsets)
    return record


def run_trial(spec: TrialSpec, config: TrialConfig = TrialConfig(), criteria=None) -> dict:
    """Runs one trial; returns its record: status "executed" (a label), "invalid" (the robot
    cannot stand at the start in this topology: no foot IK, or a leg link or the trunk already
    on the terrain) or "error" (the trial crashed; the exception is kept). Never raises for a
    failed mission: that is a label."""
    from qz_drake.capability.scenes import scene_for

    clock = time.perf_counter()
    scene = scene_for(spec.seed, spec.scene)
    heading, offsets, _ = start_of(spec, config)
    record = base_record(spec, config, scene)
    hm = scene.heightmap
    ground = float(ground_reference(hm, 0.0, 0.0))
    record["patch"] = sample_patches(hm, 0.0, 0.0, heading, spec.kind, ground=ground)
    try:
        from qz_drake.robot.topology import get_topology
        from qz_drake.simulation import SETTLE_TIME, feet_in_world, walk
        from qz_drake.scene import standing_state

        scenario, _ = trial_scenario(spec, config, criteria)
        params = scenario_params(scenario)
        try:
            x0 = standing_state(hm, get_topology(spec.topology, params), (0.0, 0.0), heading, params,
                                foot_offsets=offsets)
        except QzError as e:  # the topology cannot stand here: no mission to label
            record["time_total_s"] = time.perf_counter() - clock
            return _error_record(record, f"start not standable: {e}", status="invalid")
        feet = feet_in_world(x0[None], params)[0]
        record["feet"] = feet_in_heading_frame(feet, 0.0, 0.0, heading, ground)
        result = walk(scenario, heightmap=hm, stop_on_failure=True, blc_params=trial_blc_parameters(config),
                      blc_ladder=config.blc_ladder or None)
    except Exception as e:  # a crash of the trial, not a label: recorded and excluded
        record["time_total_s"] = time.perf_counter() - clock
        return _error_record(record, f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}")
    m = result.metrics
    total = time.perf_counter() - clock
    first_contact = m.get("first_body_contact_s")
    if first_contact is not None and first_contact < SETTLE_TIME:
        # Touching before the mission began: the start itself is invalid (a previous mission
        # that ended like this would have failed), not a label of this mission.
        record["time_total_s"] = total
        return _error_record(record, f"start not standable: {m.get('reason', '')}", status="invalid")
    blc_reasons = [r for r in m.get("reasons", []) if r.startswith("blc_")]
    record.update(
        status="executed", success=bool(m["success"]), reason=m["reasons"][0] if m.get("reasons") else "",
        message=str(m.get("reason", ""))[:200], blc_success=m.get("blc_solves", 0) > 0 and not blc_reasons
        and m.get("blc_failures", 0) == 0,
        blc_reason=str(m.get("reason", ""))[:200] if blc_reasons else "",
        blc_iterations=int(m.get("blc_iterations", 0)),
        final_xy_error_m=float(m.get("final_xy_error_m", math.nan)),
        final_yaw_error_deg=float(m.get("final_yaw_error_deg", math.nan)),
        max_tilt_deg=float(m.get("max_tilt_deg", math.nan)),
        max_joint_error_deg=float(m.get("max_joint_error_deg", math.nan)),
        max_foot_slip_m=float(m.get("max_foot_slip_m", math.nan)),
        max_leg_link_force_n=float(m.get("max_leg_link_force_n", math.nan)),
        sim_time_s=float(m.get("sim_time_s", 0.0)),
        time_solve_s=float(m.get("blc_solve_time_s", 0.0)),
        time_sim_s=max(float(m.get("wall_time_s", 0.0)) - float(m.get("blc_solve_time_s", 0.0)), 0.0),
        time_total_s=total,
    )
    record["time_build_s"] = max(total - float(m.get("wall_time_s", total)), 0.0)
    return record


def trial_blc_parameters(config: TrialConfig):
    """The BLC's parameters in a trial: the defaults with the trial's deterministic budget."""
    from qz_drake.trajopt.parameters import BlcParameters

    return BlcParameters(max_iterations=config.blc_max_iterations, time_limit=config.blc_time_limit,
                         terminal_stance=config.blc_terminal_stance)


def scenario_params(scenario):
    from qz_drake.robot.params import DEFAULT_PARAMS

    return dataclasses.replace(DEFAULT_PARAMS, payload_mass=scenario.robot.payload_kg)
