"""Capability trials that look like walks (issue 37): episodes of chained missions.

A one-move trial starts from a standing pose and labels one mission. A walk's mission starts
where the last one ended (often on a step or between boxes), is commanded by CapPlanner's
guidance (forward one cell along the current heading, or a 45 deg turn) and fails on what ends
walks. An episode is such a walk on one capability scene: from the scene's start, standing in
one topology with perturbed feet, a chain of EPISODE_MISSIONS commands drawn like the
planner's actions (forward: orthogonal or diagonal as the heading is, turns left and right),
walked in Drake by the walk's own BLC system, tracker and verdict (qz_drake.simulation with a
FixedRoute). Every mission the robot set out on is a labelled sample, with its own height
patch and start feet (where the BLC planned it from), judged on its own stretch of the walk
by the strict verdict; the first failure ends the episode, as it ends a walk.

A capability scene reaches 2.5 m from the start: room for one forward move in most
directions, so that a first probe's chains were 71 % turns (BENCHMARKS "capability", session
34). An episode walks the scene extended to EPISODE_HALF_SIZE by continuing its border (a stair
flight's levels, a slope's plane, a box field's ground run on; padded_scene_map), and its
commands never take the robot beyond SCENE_EDGE_MARGIN inside that (a forward move that would is
drawn again as a turn), so that a mission's patch and the simulated terrain cover where it goes.
The simulation holds the route's surroundings only (TRIAL_REGION_MARGIN around it).

Topology switches are samples of their own (kind "switch"): before each move or turn, with
SWITCH_PROBABILITY, the episode changes to another topology drawn uniformly, as CapPlanner's
routes do at a cell where the next action is in another topology. The BLC system switches the
standing robot (qz_drake.systems.topology_switch) and then plans the move in the new topology.
A switch's record has the new topology in ``topology`` and the one it switched from as its
index in TOPOLOGY_NAMES in ``direction``; its patch is a turn's (around the body), its window
the switch (from its start to the next mission's plan); "no plan" is a switch refused before it
started (a leg would pass the terrain, or the robot cannot stand in the new topology there).
"""

from __future__ import annotations

import dataclasses
import math
import time
import traceback

import numpy as np

from qz_drake.capability.patches import (HEADING_STEP, feet_in_heading_frame, ground_reference,
                                         move_distance, sample_patches)
from qz_drake.capability.trials import TrialConfig, blank_record, trial_blc_parameters
from qz_drake.errors import QzError, bad_value
from qz_drake.robot.params import DEFAULT_PARAMS
from qz_drake.robot.topology import TOPOLOGY_NAMES
from qz_drake.verdict import blc_failure_code

# Missions in an episode (the first failure ends it earlier).
EPISODE_MISSIONS = 4
# How likely each command is: forward, turn left, turn right (CapPlanner's routes are mostly
# forward moves with a turn every few cells).
COMMAND_WEIGHTS = {"forward": 0.6, "left": 0.2, "right": 0.2}
# An episode's map reaches this far from the start: the scene, its border continued. [m]
EPISODE_HALF_SIZE = 4.0
# A mission's end stays this far inside the map's edge (the robot's feet reach about 0.9 m
# from its centre). [m]
SCENE_EDGE_MARGIN = 1.0
# How likely a switch to another topology precedes each move or turn.
SWITCH_PROBABILITY = 0.15
# Simulated time after an episode's last planned mission, before its verdict. [s]
SETTLE_AFTER = 0.5


@dataclasses.dataclass(frozen=True)
class EpisodeSpec:
    """Everything an episode depends on (small: it travels to worker processes)."""

    seed: int
    index: int
    scene: int
    topology: str

    @property
    def episode_id(self) -> str:
        return f"{self.seed}-e{self.index}"


def episode_specs(seed: int, scenes: int, *, topologies=TOPOLOGY_NAMES) -> list[EpisodeSpec]:
    """One episode per scene and topology, in index order."""
    for t in topologies:
        if t not in TOPOLOGY_NAMES:
            raise bad_value("topologies", t, f"expected some of {', '.join(TOPOLOGY_NAMES)}")
    return [EpisodeSpec(seed, scene * len(TOPOLOGY_NAMES) + TOPOLOGY_NAMES.index(t), scene, t)
            for scene in range(scenes) for t in TOPOLOGY_NAMES if t in topologies]


@dataclasses.dataclass(frozen=True)
class Mission:
    """One command of an episode: its kind (orthogonal, diagonal, turn or switch), the turn's
    direction (0 left, 1 right; -1 for a move; for a switch the index in TOPOLOGY_NAMES of the
    topology it switches from), the pose it ends in (x, y, yaw) and the topology it is in."""

    kind: str
    direction: int
    target: tuple[float, float, float]
    topology: str


class CommandDraw:
    """Draws the planner's actions one at a time from where the robot stands (x, y, heading
    index h, topology), from ``rng``: before each but the first, with SWITCH_PROBABILITY, a
    switch to another topology drawn uniformly (``switch``); then forward, left or right with
    COMMAND_WEIGHTS, a forward move that would end beyond ``half_size - SCENE_EDGE_MARGIN``
    drawn again as a turn (``move``). An episode draws its whole chain ahead
    (episode_commands); a plan chain draws as it goes, closing the commands refused at a stance
    (plan_chains)."""

    def __init__(self, rng, half_size: float):
        self.rng = rng
        self.limit = half_size - SCENE_EDGE_MARGIN
        self.names = list(COMMAND_WEIGHTS)
        weights = np.array([COMMAND_WEIGHTS[n] for n in self.names])
        self.p = weights / weights.sum()

    def switch(self, first: bool, x: float, y: float, h: int, topology: str) -> Mission | None:
        """The switch before the next action, or None (never before the first)."""
        if first or self.rng.random() >= SWITCH_PROBABILITY:
            return None
        others = [t for t in TOPOLOGY_NAMES if t != topology]
        new = others[int(self.rng.integers(0, len(others)))]
        return Mission("switch", TOPOLOGY_NAMES.index(topology), (x, y, h * HEADING_STEP), new)

    def move(self, x: float, y: float, h: int, topology: str,
             refused: frozenset = frozenset()) -> tuple[Mission | None, int, str]:
        """(the action, the heading index it ends in, its name: forward, left or right), drawn
        among the commands not ``refused`` at this stance; (None, h, "") when every one is."""
        open_ = [k for k, n in enumerate(self.names) if n not in refused]
        if not open_:
            return None, h, ""
        p = self.p if len(open_) == len(self.names) else self.p[open_] / self.p[open_].sum()
        command = self.names[open_[int(self.rng.choice(len(open_), p=p))]]
        yaw = h * HEADING_STEP
        if command == "forward":
            kind = "diagonal" if h % 2 else "orthogonal"
            d = move_distance(kind)
            nx, ny = x + d * math.cos(yaw), y + d * math.sin(yaw)
            if max(abs(nx), abs(ny)) <= self.limit:
                return Mission(kind, -1, (nx, ny, yaw), topology), h, command
            turns = [t for t in ("left", "right") if t not in refused]
            if not turns:
                return None, h, ""
            command = turns[0] if len(turns) == 1 else ("left" if self.rng.random() < 0.5 else "right")
        h = (h + (1 if command == "left" else -1)) % 8
        return Mission("turn", 0 if command == "left" else 1, (x, y, h * HEADING_STEP), topology), h, command


def episode_commands(spec: EpisodeSpec, half_size: float, config: TrialConfig = TrialConfig()
                     ) -> tuple[float, np.ndarray, list[Mission]]:
    """(start heading [rad], start foot offsets (6, 2) [m], missions) of an episode: the
    heading one of the planner's eight, the feet perturbed like a one-move trial's, the
    commands drawn with COMMAND_WEIGHTS from the episode's seed, EPISODE_MISSIONS moves and
    turns, each preceded by a switch with SWITCH_PROBABILITY."""
    rng = np.random.default_rng([spec.seed, spec.scene, spec.index, 0xE915])
    heading_index = int(rng.integers(0, 8))
    offsets = rng.uniform(-config.foot_offset, config.foot_offset, (6, 2))
    draw = CommandDraw(rng, half_size)
    x = y = 0.0
    h = heading_index
    topology = spec.topology
    missions = []
    for _ in range(EPISODE_MISSIONS):
        # Never before the first mission: the episode's topology is drawn already (and a walk
        # whose first mission is not planned is not simulated, so the switch would not run).
        switch = draw.switch(not missions, x, y, h, topology)
        if switch is not None:
            missions.append(switch)
            topology = switch.topology
        mission, h, _ = draw.move(x, y, h, topology)
        missions.append(mission)
        x, y = mission.target[0], mission.target[1]
    return heading_index * HEADING_STEP, offsets, missions


def padded_scene_map(heightmap, half_size: float):
    """The scene's map extended to ``half_size`` around the start by continuing its border
    cells outwards (the same resolution; its own cells unchanged)."""
    from qz_drake.terrain.heightmap import HeightMap

    res = heightmap.resolution
    H, W = heightmap.heights.shape
    x0, y0 = heightmap.origin
    left = max(0, int(math.ceil((x0 + half_size) / res - 1e-9)))
    right = max(0, int(math.ceil((half_size - (x0 + (W - 1) * res)) / res - 1e-9)))
    below = max(0, int(math.ceil((y0 + half_size) / res - 1e-9)))
    above = max(0, int(math.ceil((half_size - (y0 + (H - 1) * res)) / res - 1e-9)))
    pad = ((below, above), (left, right))
    materials = None if heightmap.materials is None else np.pad(heightmap.materials, pad, mode="edge")
    return HeightMap(heights=np.pad(heightmap.heights, pad, mode="edge"), resolution=res,
                     origin=(x0 - left * res, y0 - below * res), materials=materials,
                     material_names=heightmap.material_names)


def episode_scenario(spec: EpisodeSpec, missions: list[Mission], heading: float, offsets: np.ndarray,
                     config: TrialConfig, half_size: float, criteria=None):
    """The walking scenario of an episode: its missions as a route of waypoints, one mission
    each (the map is passed to the station apart); the simulated region the route's
    surroundings."""
    from qz_drake.capability.trials import TRIAL_REGION_MARGIN
    from qz_drake.config import (ControllerConfig, RobotConfig, Scenario,
                                 SuccessCriteria, TerrainConfig, Waypoint)

    # Every mission's duration rounds up to whole tripod cycles, at most two more than its
    # distance at the mission speed, and the BLC may retry none: 3 s a mission is ample.
    # A switch takes about 4.9 s (SwitchTiming: six legs in turn): 6 s.
    moves = [m for m in missions if m.kind != "switch"]
    # With the BLC ladder each mission may take a longer rung's plan (config.ladder_allowance).
    duration = sum(move_distance(m.kind) / config.speed + 3.0 + config.ladder_allowance for m in moves) \
        + 6.0 * (len(missions) - len(moves)) + 1.0
    xs = [0.0] + [m.target[0] for m in missions]
    ys = [0.0] + [m.target[1] for m in missions]
    station, simulation = config.station_and_simulation(duration)
    r = TRIAL_REGION_MARGIN
    region = [max(min(xs) - r, -half_size), min(max(xs) + r, half_size),
              max(min(ys) - r, -half_size), min(max(ys) + r, half_size)]
    return Scenario(
        name=f"episode_{spec.episode_id}",
        description="capability episode",
        terrain=TerrainConfig(kind="flat", region=region),
        robot=RobotConfig(topology=spec.topology, initial_xy=[0.0, 0.0], initial_yaw=heading,
                          initial_foot_offsets=offsets.tolist()),
        simulation=simulation,
        station=station,
        controller=ControllerConfig(kind="walk", planner="blc",
                                    # A switch is the next move's topology (the BLC system switches
                                    # the standing robot before it plans that move).
                                    route=[Waypoint(x=m.target[0], y=m.target[1], yaw=m.target[2],
                                                    topology=m.topology) for m in moves],
                                    # One route leg, one mission (the longest is a diagonal cell).
                                    mission_length=move_distance("diagonal") + 0.01,
                                    speed=config.speed, phase_duration=config.phase_duration,
                                    kp=config.kp, kd=config.kd),
        success=criteria or SuccessCriteria(),
    )


def _record(spec: EpisodeSpec, scene, position: int, mission: Mission) -> dict:
    record = blank_record()
    record.update(index=spec.index, scene=spec.scene, heading_sample=position, scene_kind=scene.kind,
                  difficulty=scene.difficulty, scene_seed=scene.seed, topology=mission.topology,
                  kind=mission.kind, direction=mission.direction, status="executed")
    return record


def episode_error_record(spec: EpisodeSpec, message: str) -> dict:
    """The record of an episode that crashed (status "error", kept and excluded from training)."""
    from qz_drake.capability.scenes import scene_for

    _, _, missions = episode_commands(spec, EPISODE_HALF_SIZE)
    record = _record(spec, scene_for(spec.seed, spec.scene), 0, missions[0])
    record.update(status="error", error=message[:400])
    return record


def _mission_inputs(record: dict, heightmap, start_xy_yaw, feet_W) -> None:
    """The network's inputs of a mission that starts at (x, y, yaw) with its feet feet_W."""
    x, y, yaw = start_xy_yaw
    ground = float(ground_reference(heightmap, x, y))
    record["heading"] = float(yaw)
    # A switch's patch is a turn's: the ground around the body.
    kind = "turn" if record["kind"] == "switch" else record["kind"]
    record["patch"] = sample_patches(heightmap, x, y, yaw, kind, ground=ground)
    record["feet"] = feet_in_heading_frame(np.asarray(feet_W, dtype=float), x, y, yaw, ground)


def run_episode(spec: EpisodeSpec, config: TrialConfig = TrialConfig(), criteria=None) -> list[dict]:
    """Walks an episode; returns one record per mission the robot set out on (the trials'
    record fields; ``heading_sample`` holds the mission's place in the chain, ``time_total_s``
    the episode's wall time shared evenly). The first failed mission is the last record; a
    start the topology cannot stand on gives one ``invalid`` record, a crash one ``error``
    record (never raised)."""
    from qz_drake.capability.scenes import scene_for

    clock = time.perf_counter()
    scene = scene_for(spec.seed, spec.scene)
    heading, offsets, missions = episode_commands(spec, EPISODE_HALF_SIZE, config)
    hm = padded_scene_map(scene.heightmap, EPISODE_HALF_SIZE)
    scene = dataclasses.replace(scene, heightmap=hm)
    return walk_episode(spec, scene, heading, offsets, missions, config, criteria, clock)


def walk_episode(spec, scene, heading: float, offsets: np.ndarray, missions: list[Mission],
                 config: TrialConfig = TrialConfig(), criteria=None, clock: float | None = None) -> list[dict]:
    """Walks the ``missions`` of an episode from the start (0, 0) facing ``heading`` with the
    feet ``offsets`` from the topology's footholds, on ``scene.heightmap`` (a map that reaches
    EPISODE_HALF_SIZE around the start), and labels them as :func:`run_episode` does. ``spec``
    needs ``index``, ``scene``, ``topology`` and ``episode_id``; ``scene`` ``kind``,
    ``difficulty``, ``seed`` and ``heightmap`` (the records' scene fields). The episodes of
    the planners' own routes (qz_drake.experiments.route_episodes) start this way from the
    stances their walks stood in."""
    from qz_drake.scene import standing_state
    from qz_drake.robot.topology import get_topology
    from qz_drake.simulation import SETTLE_TIME, build_walk, feet_in_world, judge_walk_run, run_walk

    clock = time.perf_counter() if clock is None else clock
    hm = scene.heightmap
    first = _record(spec, scene, 0, missions[0])
    try:
        scenario = episode_scenario(spec, missions, heading, offsets, config, EPISODE_HALF_SIZE, criteria)
        params = dataclasses.replace(DEFAULT_PARAMS, payload_mass=scenario.robot.payload_kg)
        try:
            x0 = standing_state(hm, get_topology(spec.topology, params), (0.0, 0.0), heading, params,
                                foot_offsets=offsets)
        except QzError as e:
            first.update(status="invalid", error=f"start not standable: {e}"[:400],
                         time_total_s=time.perf_counter() - clock)
            return [first]
        built = build_walk(scenario, heightmap=hm, blc_params=trial_blc_parameters(config),
                           blc_ladder=config.blc_ladder or None)
        run = None if not hasattr(built, "diagram") else run_walk(built, scenario, stop_on_failure=True)
    except Exception as e:  # a crash of the episode, not a label
        first.update(status="error", error=f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}"[:400],
                     time_total_s=time.perf_counter() - clock)
        return [first]
    start_feet = feet_in_world(x0[None], params)[0]
    if run is None or not hasattr(run, "simulator"):  # the first mission was not planned
        not_started = run if run is not None else built
        _mission_inputs(first, hm, (0.0, 0.0, heading), start_feet)
        first.update(success=False, reason=blc_failure_code(not_started.reason), blc_success=False,
                     message=not_started.reason[:200], blc_reason=not_started.reason[:200],
                     blc_iterations=_iterations(built, 0) if hasattr(built, "missions") else 0,
                     time_total_s=time.perf_counter() - clock)
        return [first]
    result = judge_walk_run(scenario, built, run)
    records = _label_missions(spec, scene, missions, built, run, result, scenario.success)
    first_contact = result.metrics.get("first_body_contact_s")
    if first_contact is not None and first_contact < SETTLE_TIME:
        # Touching before the first mission began: the start is invalid, not a label.
        records = [dict(records[0], status="invalid", success=False,
                        error=f"start not standable: {result.metrics.get('reason', '')}"[:400])]
    total = time.perf_counter() - clock
    for r in records:
        r["time_total_s"] = total / len(records)
    return records


def _label_missions(spec, scene, missions, built, run, result, criteria) -> list[dict]:
    """One record per mission the robot set out on, each judged on its own stretch of the walk:
    a move or turn from its plan's start to the next switch's or plan's start (the last: to the
    end of the run), a switch from its start to the next plan's."""
    from qz_drake.capability.walk_missions import WalkWindows

    log = built.missions.log
    plans = log.plans
    failures = dict(log.failures)
    switches = list(built.missions.blc.log.switches)
    windows = WalkWindows(built, run, result, criteria)
    times, end, measured_at = windows.times, windows.end, windows.measured_at

    def judge(record, t0, t1, goal, last):
        verdict, seconds = windows.judge(t0, t1, goal, last)
        m = verdict.measures
        record.update(
            success=bool(verdict.success), reason=verdict.reasons[0] if verdict.reasons else "",
            message="; ".join(verdict.messages)[:200], blc_success=True,
            final_xy_error_m=float(m["final_xy_error_m"]), final_yaw_error_deg=float(m["final_yaw_error_deg"]),
            max_tilt_deg=float(m["max_tilt_deg"]), max_joint_error_deg=float(m["max_joint_error_deg"]),
            max_foot_slip_m=float(m["max_foot_slip_m"]), max_leg_link_force_n=float(m["max_leg_link_force_n"]),
            sim_time_s=seconds)
        return verdict.success

    def no_plan(record, reason, k):
        record.update(success=False, reason=blc_failure_code(reason), message=reason[:200], blc_success=False,
                      blc_reason=reason[:200], blc_iterations=_iterations(built, k))

    records = []
    j = 0  # the next move's (or turn's) plan
    s = 0  # the next switch the BLC system made
    for k, mission in enumerate(missions):
        record = _record(spec, scene, k, mission)
        if mission.kind == "switch":
            refused = failures.get(j, "")
            if refused.startswith("topology switch"):
                pose, feet = measured_at(_solve_time(built, j))
                _mission_inputs(record, scene.heightmap, pose, feet)
                no_plan(record, refused, j)
                records.append(record)
                break
            if s >= len(switches):  # the run ended before it
                break
            switch = switches[s]
            s += 1
            if j >= len(plans):  # the move after it was refused: the switch never ran
                continue
            pose, feet = measured_at(switch.start_time)
            _mission_inputs(record, scene.heightmap, pose, feet)
            t1 = plans[j].start_time
            records.append(record)
            if not judge(record, switch.start_time, t1, pose, last=times[-1] < t1):
                break
        elif j < len(plans):
            plan = plans[j]
            t0 = plan.start_time
            # Where the BLC planned it from (a walk's mission: the state measured there).
            base, rpy = plan.base_position(t0), plan.base_rpy(t0)
            _mission_inputs(record, scene.heightmap, (float(base[0]), float(base[1]), float(rpy[2])),
                            plan.foot_positions(t0))
            nxt = missions[k + 1] if k + 1 < len(missions) else None
            if nxt is not None and nxt.kind == "switch" and s < len(switches):
                t1 = switches[s].start_time
            else:
                t1 = plans[j + 1].start_time if j + 1 < len(plans) else end
            last = times[-1] < t1
            record["blc_iterations"] = _iterations(built, j)
            j += 1
            records.append(record)
            if not judge(record, t0, t1, mission.target, last):
                break
        elif j in failures:  # the BLC could not plan it: from the state it was given
            after_switch = k > 0 and missions[k - 1].kind == "switch" and s > 0
            if after_switch:  # planned from where the switch would have put the feet
                switch = switches[s - 1]
                pose, _ = measured_at(switch.start_time)
                feet = np.asarray(switch.end_feet, dtype=float)
            else:
                pose, feet = measured_at(_solve_time(built, j))
            _mission_inputs(record, scene.heightmap, pose, feet)
            no_plan(record, failures[j], j)
            records.append(record)
            break
        else:  # the run ended before this mission was given (a fall or a stop in the last)
            break
    return records


def _mission_solves(built, k: int) -> list:
    """The BLC's solves of mission k (a retry repeats its target)."""
    missions = []
    for s in built.missions.blc.log.solves:
        if not missions or s.target != missions[-1][0].target:
            missions.append([])
        missions[-1].append(s)
    return missions[k] if k < len(missions) else []


def _iterations(built, k: int) -> int:
    """Ipopt iterations of the solves of mission k."""
    return int(sum(s.iterations for s in _mission_solves(built, k)))


def _solve_time(built, k: int) -> float:
    """When mission k was to start (its first solve's start time; 0 if it had none). [s]"""
    solves = _mission_solves(built, k)
    return float(solves[0].start_time) if solves else 0.0
