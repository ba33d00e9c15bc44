"""Every mission of a whole walk, judged on its own stretch (issue 37): what the capability model
must predict when it plans walks.

A walk hands the BLC one mission after another (a fixed route's, A*'s with its recovery,
CapPlanner's). Each mission ends in one of the three outcomes the networks predict: the BLC
found no plan (the robot stood where it was), or it was executed and walked, or executed and
failed (a fall, a leg or the trunk on the terrain, a slip, a missed target). :class:`WalkWindows`
judges a stretch of a finished walk with the strict verdict (qz_drake.verdict.judge_walk), the
same judgement the capability episodes give their missions (capability/episodes.py);
:func:`walk_mission_records` lists a walk's missions with where each started (the pose and
feet the BLC planned it from), its target and topology, and its outcome, so that a model can
be scored on walks it never saw (the Fig. 9 experiment's ``record_missions``).
"""

from __future__ import annotations

import math

import numpy as np

from qz_drake.state_layout import BASE_XY, base_rpy
from qz_drake.verdict import blc_failure_code, judge_walk

# A mission's three outcomes, as the networks order them (capability.training.OUTCOMES).
WALKED, NO_PLAN, FAILED = "walked", "no_plan", "failed"


class WalkWindows:
    """A finished walk's logs (build_walk, run_walk, judge_walk_run), judged stretch by stretch."""

    def __init__(self, built, run, result, criteria):
        from qz_drake.simulation import feet_in_world

        self.built, self.run, self.result, self.criteria = built, run, result, criteria
        self.times, self.states = result.times, result.states
        self.desired = built.logs["desired"].FindLog(run.context).data().T
        self.links = built.logs["leg"].FindLog(run.context).data().T if built.logs["leg"] is not None else None
        self.selfc = built.logs["self"].FindLog(run.context).data()[0] if built.logs["self"] is not None else None
        self.feet_W = feet_in_world(self.states, built.info.params)
        # Later than every sample: the end of a stretch that runs to the end of the walk.
        self.end = float(self.times[-1]) + 1e-9

    def judge(self, t0: float, t1: float, goal, last: bool):
        """The strict verdict of the samples in [t0, t1) against ``goal`` (x, y, yaw); ``last``:
        the stretch ends the walk (a fall or a timeout then counts in it). Returns (verdict,
        simulated seconds of the stretch)."""
        times = self.times
        window = (times >= t0 - 1e-9) & (times < t1)
        n = int(window.sum())
        run = self.run
        verdict = judge_walk(
            self.criteria, goal_xy_yaw=goal, times=times[window], states=self.states[window],
            desired_q=self.desired[window], feet_W=self.feet_W[window], contacts=self.result.foot_contact[window],
            trunk=self.result.trunk_contact[window],
            leg_link_force=np.zeros((n, 6)) if self.links is None else self.links[window],
            self_force=np.zeros(n) if self.selfc is None else self.selfc[window],
            fell=run.fell and last, timed_out=last and not run.stopped and not run.fell
            and not self.built.missions.done)
        return verdict, (float(times[window][-1] - times[window][0]) if n else 0.0)

    def measured_at(self, t: float):
        """((x, y, yaw), feet (6, 3)) of the robot at the first sample from time t on."""
        i = min(int(np.searchsorted(self.times, t)), len(self.times) - 1)
        x = self.states[i]
        return (float(x[BASE_XY][0]), float(x[BASE_XY][1]), float(base_rpy(x)[2])), self.feet_W[i]


def mission_timeline(plans, solves, retried, switches, end: float) -> list[dict]:
    """The missions of a walk in the order the BLC met them, from its logs alone: one entry per
    mission (a solve that no retry followed), ``planned`` with its plan or refused, with
    ``t0`` (when its plan starts or would have started), ``switch`` (the topology switch made
    for it, or None), ``begin`` (the switch's start, else t0) and, for planned ones, ``t1``:
    where its stretch ends, the first other mission's ``begin`` after its own t0 (else ``end``).

    A switch belongs to the first mission planned from its end, refused or not: a mission the
    BLC refused right after the switch made for it leaves the next one (solved from the same
    end state) without a switch. A refused mission starts no stretch of its own unless it had a
    switch (the robot reconfigured for it); one refused while the previous plan still ran
    (solved from that plan's expected end) starts where that plan ends, so it cuts no plan short."""
    retried = set(retried)
    missions = [s for i, s in enumerate(solves) if i not in retried]
    owner: dict[int, object] = {}
    for switch in switches:
        if not math.isfinite(switch.end_time):
            continue
        for j, s in enumerate(missions):
            if j not in owner and abs(s.start_time - switch.end_time) < 1e-6:
                owner[j] = switch
                break
    remaining = list(plans)
    out = []
    for j, s in enumerate(missions):
        entry = {"solve": s, "planned": bool(s.success), "t0": float(s.start_time), "switch": owner.get(j), "plan": None}
        if s.success:
            # The plan of this solve: the logged one that starts when it was to start. One the
            # sequencer never saw (the walk ended first) is no mission walked.
            match = next((k for k, plan in enumerate(remaining) if abs(plan.start_time - s.start_time) < 1e-6), None)
            if match is None:
                continue
            entry["plan"] = remaining.pop(match)
        entry["begin"] = float(entry["switch"].start_time) if entry["switch"] is not None else entry["t0"]
        out.append(entry)
    for e in out:
        if e["planned"]:
            later = [o["begin"] for o in out if o is not e and (o["planned"] or o["switch"] is not None)
                     and o["begin"] > e["t0"] + 1e-9]
            e["t1"] = min(later) if later else end
    return out


def walk_mission_records(built, run, result, criteria) -> list[dict]:
    """One record per mission the walk's BLC was given, in the order they started: planned
    ones judged on their stretch (from the mission's start, or the topology switch made for it,
    to the next mission's; :func:`mission_timeline`), refused ones as "no plan" from the state
    the BLC planned them from (or "failed" when the switch made for them failed the verdict).
    Each record: ``start_time`` [s], ``start`` (x, y, yaw) and ``feet`` (6, 3) in the world where
    the BLC planned it from [m, rad], ``target`` (x, y, yaw), ``topology``, ``switched_from``
    (the topology of a switch made for it, "" without), ``outcome`` (walked, no_plan, failed),
    ``reason`` (the verdict's first, or the BLC's failure code), ``message``, ``sim_time_s``;
    a planned one also ``rung``, the rung of the BLC ladder that planned it ("": its first
    solve); a refused one ``blc_start``, the mission start the BLC was given (``xy_yaw``,
    ``base_z``, ``roll_pitch``, ``feet``). JSON-ready."""
    windows = WalkWindows(built, run, result, criteria)
    log = built.missions.log
    blc = built.missions.blc.log
    timeline = mission_timeline(log.plans, blc.solves, blc.retried, blc.switches, windows.end)
    targets = {id(plan): (log.targets[i] if i < len(log.targets) else None) for i, plan in enumerate(log.plans)}
    topologies = {id(plan): (log.topologies[i] if i < len(log.topologies) else "") for i, plan in enumerate(log.plans)}
    records = []
    for e in timeline:
        s, switch = e["solve"], e["switch"]
        if e["planned"]:
            plan, t0 = e["plan"], e["t0"]
            base, rpy = plan.base_position(t0), plan.base_rpy(t0)
            target = targets.get(id(plan)) or (*np.asarray(plan.base_position(plan.end_time))[:2],
                                               float(plan.base_rpy(plan.end_time)[2]), "")
            verdict, seconds = windows.judge(e["begin"], e["t1"], tuple(float(v) for v in target[:3]),
                                             last=windows.times[-1] < e["t1"])
            records.append({"start_time": e["begin"], "start": [float(base[0]), float(base[1]), float(rpy[2])],
                            "feet": np.asarray(plan.foot_positions(t0), dtype=float).round(5).tolist(),
                            "target": [float(v) for v in target[:3]],
                            "topology": topologies.get(id(plan)) or s.topology,
                            "switched_from": switch.from_topology if switch else "",
                            "outcome": WALKED if verdict.success else FAILED,
                            "reason": verdict.reasons[0] if verdict.reasons else "",
                            "message": "; ".join(verdict.messages)[:200], "sim_time_s": seconds,
                            "rung": s.rung})
            continue
        pose, feet = windows.measured_at(e["t0"])
        record = {"start_time": e["begin"], "start": list(pose), "feet": np.asarray(feet, dtype=float).round(5).tolist(),
                  "target": [float(v) for v in s.target], "topology": s.topology,
                  "switched_from": switch.from_topology if switch else "", "outcome": NO_PLAN,
                  "reason": blc_failure_code(s.reason), "message": s.reason[:200], "sim_time_s": 0.0}
        if s.start:  # the BLC's own inputs, to solve the mission again (benchmarks/blc_refusals.py)
            record["blc_start"] = {"xy_yaw": list(s.start[:3]), "base_z": s.start[3],
                                   "roll_pitch": list(s.start[4:6]),
                                   "feet": [list(foot) for foot in s.start_feet]}
        if switch is not None:  # the robot reconfigured for it: the switch itself judged
            before, _ = windows.measured_at(switch.start_time)
            later = [o["begin"] for o in timeline if o is not e and o["begin"] > switch.start_time + 1e-9]
            t1 = min([switch.end_time, *later])
            verdict, seconds = windows.judge(switch.start_time, t1, before, last=windows.times[-1] < t1)
            record["sim_time_s"] = seconds
            if not verdict.success and set(verdict.reasons) - {"missed_target"}:
                record.update(outcome=FAILED, reason=next(r for r in verdict.reasons if r != "missed_target"),
                              message="; ".join(verdict.messages)[:200])
        records.append(record)
    records.sort(key=lambda r: r["start_time"])
    for k, r in enumerate(records):
        r["index"] = k
    return records
