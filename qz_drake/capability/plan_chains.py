"""Labels of the BLC alone (issues 53 and 54): chains of missions planned and never walked.

Whether the BLC finds a plan for a mission needs no simulation: it is decided by the mission's
start (the pose and the feet it plans from), its target and the map. A plan chain is an
episode (capability/episodes.py) that the BLC plans without the robot walking it: from the
scene's start, standing in one topology with perturbed feet, commands drawn like the planner's
actions (forward along the heading, 45 deg turns, and before each, with SWITCH_PROBABILITY, a
switch to another topology) are planned one after the other, each from the end state the plan
before it expects (the BLC system's plan-ahead start, ``blc_plan.expected_end``). A refused
mission leaves the robot standing where it was, as in a walk, and the chain goes on from there
with another command (the refused one closed there until the robot moves or switches, as
CapPlanner closes a refused action; a stance from which all three are refused ends the chain);
so a chain also labels the stances a refusal leaves behind, which walks meet and one-move
trials never do.

Every mission is a record of status ``blc_only`` with the trials' fields: its inputs (height
patch, start feet) and ``blc_success``, ``blc_reason``, ``blc_iterations``, ``reason`` (the
refusal's failure code, "" for a plan). Whether a planned mission would have been *walked* is
not measured: ``success`` is False and means nothing in these records; the simulated episodes
label execution. A chain costs the BLC's solves and the scene's setup only, so it labels many
more starts an hour (BENCHMARKS "capability").

The BLC is the trials' (trial_blc_parameters; with the trials' ``blc_ladder`` a refused mission
is solved again on its rungs in order, as the BLC system does, and labelled planned if one
plans: :func:`solve_on_ladder`), the mission timing theirs, the switch the BLC system's (plan_topology_switch from the standing
robot). Unlike a simulated episode, a start whose trunk or legs would touch the terrain once
the robot settles is not found (nothing settles); the feet are where the plan put them, not
where the robot's would be. That difference shows: a plan learner fed 6 190 chain labels told
the chains' held-out refusals better and walks' refusals a little worse (BENCHMARKS
"capability", session 46).
"""

from __future__ import annotations

import dataclasses
import time
import traceback

import numpy as np

from qz_drake.capability.episodes import (EPISODE_HALF_SIZE, CommandDraw, EpisodeSpec, Mission, _mission_inputs,
                                          _record, padded_scene_map)
from qz_drake.capability.patches import HEADING_STEP
from qz_drake.capability.trials import TrialConfig, trial_blc_parameters
from qz_drake.errors import ConfigError, QzError
from qz_drake.robot.params import DEFAULT_PARAMS
from qz_drake.verdict import blc_failure_code

# Commands in a chain (moves and turns; switches come on top of them).
CHAIN_MISSIONS = 8
# The status of a chain's records: labelled by the BLC alone.
BLC_ONLY = "blc_only"


def solve_on_ladder(planner, ladder, start, target, topology):
    """(plan or None, reason, Ipopt iterations of every solve) of a mission solved as the BLC
    system solves it (TrajectoryOptimizationBLC): first as asked, then on each rung of
    ``ladder`` in order until one plans; a mission no rung plans keeps its first solve's reason.
    No wall-time budget: the chain's labels stay a function of the mission alone."""
    first_reason, iterations = "", 0
    for k, rung in enumerate(("",) + tuple(ladder)):
        plan, reason = planner(start, target, topology, start.time, rung=rung)
        iterations += int(planner.last_iterations)
        if k == 0:
            first_reason = reason
        if plan is not None:
            return plan, "", iterations
    return None, first_reason, iterations


def run_plan_chain(spec: EpisodeSpec, config: TrialConfig = TrialConfig()) -> list[dict]:
    """Plans a chain (see the module docstring); returns one ``blc_only`` record per command,
    a switch included (a refused switch leaves the robot in its topology, and the next command
    is drawn for that). A start the topology cannot stand on gives one ``invalid`` record; a
    crash adds one ``error`` record after the labels before it (never raised)."""
    from qz_drake.capability.scenes import scene_for
    from qz_drake.config import MissionTiming
    from qz_drake.robot.topology import get_topology
    from qz_drake.scene import standing_state
    from qz_drake.systems.blc_plan import blc_mission_planner, expected_end, parse_ladder
    from qz_drake.systems.mission_sequencer import measured_start
    from qz_drake.systems.topology_switch import plan_topology_switch

    clock = time.perf_counter()
    scene = scene_for(spec.seed, spec.scene)
    hm = padded_scene_map(scene.heightmap, EPISODE_HALF_SIZE)
    scene = dataclasses.replace(scene, heightmap=hm)
    # The chain's own draws (an episode of the same spec draws its commands apart).
    rng = np.random.default_rng([spec.seed, spec.scene, spec.index, 0xB1C0])
    h = int(rng.integers(0, 8))
    draw = CommandDraw(rng, EPISODE_HALF_SIZE)
    offsets = np.random.default_rng([spec.seed, spec.scene, spec.index, 0xB1C1]).uniform(
        -config.foot_offset, config.foot_offset, (6, 2))
    records: list[dict] = []
    first = _record(spec, scene, 0, Mission("turn", 0, (0.0, 0.0, h * HEADING_STEP), spec.topology))
    first.update(status=BLC_ONLY, heading=h * HEADING_STEP)
    try:
        try:
            x0 = standing_state(hm, get_topology(spec.topology, DEFAULT_PARAMS), (0.0, 0.0), h * HEADING_STEP,
                                DEFAULT_PARAMS, foot_offsets=offsets)
        except QzError as e:
            first.update(status="invalid", error=f"start not standable: {e}"[:400],
                         time_total_s=time.perf_counter() - clock)
            return [first]
        planner = blc_mission_planner(hm, DEFAULT_PARAMS, MissionTiming(speed=config.speed,
                                                                       phase_duration=config.phase_duration),
                                      trial_blc_parameters(config))
        ladder = parse_ladder(config.blc_ladder, "trials.blc_ladder")
        start = measured_start(x0, 0.0, DEFAULT_PARAMS)
        x = y = 0.0
        topology = spec.topology
        position = 0
        refused: set[str] = set()  # commands refused from the stance the robot stands in
        for k in range(CHAIN_MISSIONS):
            switch = draw.switch(k == 0, x, y, h, topology)
            if switch is not None:
                record = _record(spec, scene, position, switch)
                position += 1
                _mission_inputs(record, hm, start.xy_yaw, start.feet_W)
                solve = time.perf_counter()
                try:
                    plan = plan_topology_switch(heightmap=hm, start=start,
                                                from_topology=get_topology(topology, DEFAULT_PARAMS),
                                                to_topology=get_topology(switch.topology, DEFAULT_PARAMS),
                                                start_time=start.time, params=DEFAULT_PARAMS)
                except ConfigError as e:
                    reason = f"topology switch {topology} -> {switch.topology}: {e}"
                    record.update(status=BLC_ONLY, reason=blc_failure_code(reason), message=reason[:200],
                                  blc_success=False, blc_reason=reason[:200],
                                  time_solve_s=time.perf_counter() - solve)
                    records.append(record)  # the robot keeps its topology
                else:
                    record.update(status=BLC_ONLY, blc_success=True, time_solve_s=time.perf_counter() - solve)
                    records.append(record)
                    start, topology = expected_end(plan), switch.topology
                    refused.clear()
            command, heading, name = draw.move(x, y, h, topology, frozenset(refused))
            if command is None:  # a dead end: every command from here refused
                break
            record = _record(spec, scene, position, command)
            position += 1
            _mission_inputs(record, hm, start.xy_yaw, start.feet_W)
            solve = time.perf_counter()
            plan, reason, iterations = solve_on_ladder(planner, ladder, start, command.target, topology)
            record.update(status=BLC_ONLY, blc_success=plan is not None, blc_iterations=iterations,
                          time_solve_s=time.perf_counter() - solve)
            if plan is None:  # the robot stands where it was; the next command from there
                record.update(reason=blc_failure_code(reason), message=reason[:200], blc_reason=reason[:200])
                refused.add(name)
            else:
                start = expected_end(plan)
                x, y, h = command.target[0], command.target[1], heading
                refused.clear()
            records.append(record)
    except Exception as e:  # a crash of the chain, not a label
        # The labels before it stand; the crash is a record of its own (excluded from training).
        first.update(status="error", error=f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}"[:400],
                     heading_sample=len(records))
        records.append(first)
    total = time.perf_counter() - clock
    for r in records:
        r["time_total_s"] = total / len(records)
    return records


def plan_chain_error_record(spec: EpisodeSpec, message: str) -> dict:
    """The record of a chain whose worker died every time (status "error")."""
    from qz_drake.capability.scenes import scene_for

    record = _record(spec, scene_for(spec.seed, spec.scene), 0,
                     Mission("turn", 0, (0.0, 0.0, 0.0), spec.topology))
    record.update(status="error", error=message[:400])
    return record


__all__ = ["BLC_ONLY", "CHAIN_MISSIONS", "plan_chain_error_record", "run_plan_chain"]
