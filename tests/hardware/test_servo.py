"""The servo (qz_drake.hardware.servo): the joint PD answering the robot from reference tables.

The servo runs here in lockstep with the simulated robot driver over an in-process LCM, and
the test plays the planning process: it publishes tables (qz_reference) and heartbeats
(qz_planner) between the simulator's steps, as the planning process does from its own.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from pydrake.lcm import DrakeLcm

from qz_drake.config import load_scenario
from qz_drake.hardware.config import HardwareConfig
from qz_drake.hardware.interface import scenario_station_info
from qz_drake.hardware.qz_lcm import qz_planner, qz_servo
from qz_drake.hardware.references import (ROW_SIZE, ReferenceTable, decode_table, encode_table, plan_references,
                                          standing_row, table_chunks)
from qz_drake.hardware.servo import Servo
from qz_drake.simulation import _tripod_planner
from qz_drake.state_layout import BASE_POS, tilt_deg
from qz_drake.systems.blc import expected_end
from qz_drake.systems.ik_tracker import InverseKinematicsTracker
from qz_drake.systems.mission_sequencer import measured_start
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource

from pathlib import Path

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


@pytest.fixture(scope="module")
def walk_flat():
    scenario = load_scenario(SCENARIOS / "walk_flat.yaml")
    info = scenario_station_info(scenario)
    planner = _tripod_planner(info.heightmap, info.params, scenario.controller)
    # Short missions (the shortest the tripod plan makes, 1.2 s), so that the walks here are short.
    first, _ = planner(measured_start(info.initial_state, 0.5, info.params), (0.25, 0.0, 0.0), "nominal", 0.5)
    second, _ = planner(expected_end(first), (0.5, 0.0, 0.0), "nominal", first.end_time)
    return scenario, info, first, second


def test_a_table_holds_what_the_tracker_holds_at_each_update(walk_flat):
    scenario, info, plan, _ = walk_flat
    table = plan_references(plan, topology=info.topology, params=info.params)
    assert table.start_time == pytest.approx(plan.start_time) and table.end_time >= plan.end_time
    builder = DiagramBuilder()
    tracker = builder.AddSystem(InverseKinematicsTracker(topology=info.topology, params=info.params))
    source = builder.AddSystem(ConstantValueSource(AbstractValue.Make(plan)))
    builder.Connect(source.get_output_port(), tracker.GetInputPort("trajectory"))
    simulator = Simulator(builder.Build())
    context = tracker.GetMyContextFromRoot(simulator.get_context())
    for t in np.arange(plan.start_time + 0.0025, table.end_time + 0.1, 0.005)[::7]:
        simulator.AdvanceTo(t)
        assert np.array_equal(context.get_discrete_state(0).get_value(), table.row_at(t)), t
    # The last row is the plan's end stance, at rest.
    assert np.all(table.rows[-1, 18:36] == 0.0)
    message, decoded = decode_table(encode_table(table, sequence=3, utime=7))
    assert message.sequence == 3 and np.array_equal(decoded.rows, table.rows)


def test_a_newer_table_takes_over_at_its_start():
    rows = np.arange(5, dtype=float)[:, None] * np.ones(ROW_SIZE)
    old = ReferenceTable(start_time=1.0, period=0.5, rows=rows)
    assert old.end_time == 3.0 and old.row_at(0.0)[0] == 0 and old.row_at(1.74)[0] == 1 and old.row_at(9)[0] == 4
    newer = ReferenceTable(start_time=2.0, period=0.5, rows=rows[:2] + 10)
    merged = old.merged(newer)
    assert merged.rows[:, 0].tolist() == [0, 1, 10, 11] and merged.end_time == 2.5
    # A table that starts after the old one ends: the last row is held until it does.
    late = old.merged(ReferenceTable(start_time=4.0, period=0.5, rows=rows[:1] + 20))
    assert late.rows[:, 0].tolist() == [0, 1, 2, 3, 4, 4, 20]
    assert old.after(2.2).start_time == 2.0 and old.after(2.2).rows[0, 0] == 2
    with pytest.raises(Exception, match="qz_reference.period"):
        old.merged(ReferenceTable(start_time=2.0, period=0.25, rows=rows))


def test_a_malformed_table_is_named():
    table = ReferenceTable(start_time=0.0, period=0.005, rows=np.full((2, ROW_SIZE), np.nan))
    with pytest.raises(ValueError, match=r"qz_reference.rows\[0\]\[0\] = nan"):
        decode_table(encode_table(table, sequence=1, utime=0))


class FakePlanner:
    """The planning process's side of the link, driven between the servo's steps."""

    def __init__(self, lcm: DrakeLcm, config: HardwareConfig):
        self.lcm, self.config, self.sequence = lcm, config, 0
        self.servo: list[qz_servo] = []
        lcm.Subscribe(config.channels.servo, lambda data: self.servo.append(qz_servo.decode(data)))

    def beat(self, plan_time: float, finished: bool = False) -> None:
        self.sequence += 1
        m = qz_planner()
        m.utime, m.sequence, m.plan_time, m.finished = self.sequence, self.sequence, plan_time, finished
        self.lcm.Publish(self.config.channels.planner, m.encode())

    def send(self, table: ReferenceTable) -> None:
        self.lcm.Publish(self.config.channels.reference, encode_table(table, sequence=self.sequence, utime=0))


def run(servo: Servo, until: float, planner: FakePlanner, planner_time, step: float = 0.02) -> list:
    """Steps the servo to ``until``; the planner beats with planner_time(t) (None: silent).
    Returns the robot's base positions at each step."""
    positions = []
    context = servo.context
    driver_context = servo.driver.GetMyContextFromRoot(context)
    while context.get_time() < until - 1e-9:
        reached = planner_time(context.get_time())
        if reached is not None:
            planner.beat(reached)
        servo.simulator.AdvanceTo(min(until, context.get_time() + step))
        servo._sync_safe_stop(None)
        positions.append(servo.driver.GetOutputPort("true_state").Eval(driver_context).copy())
    return positions


def test_a_late_planner_holds_the_stance_and_the_walk_goes_on_when_the_plan_comes(walk_flat):
    scenario, info, first, second = walk_flat
    lcm = DrakeLcm("memq://")
    servo = Servo(scenario=scenario, lcm=lcm, with_driver=True)
    planner = FakePlanner(lcm, servo.config)
    servo.simulator.Initialize()
    planner.send(plan_references(first, topology=info.topology, params=info.params))
    # The planning process gets no further than 0.6 s: the next mission is late.
    states = run(servo, first.end_time + 1.0, planner, lambda t: min(t, 0.6))
    s = servo.player_state()
    assert s.holding and s.late_holds == 1 and s.plan_time == pytest.approx(first.end_time + 0.005)
    report = servo.report()
    assert report["safe_stop"] == "" and report["servo"]["late_hold_time_s"] > 0.8
    assert report["servo"]["commands_answering_a_status"] > 500 and report["servo"]["latency_p99_ms"] > 0
    assert report["servo"]["gc_longest_pause_ms"] >= 0  # the servo's collector is reported
    # Walked the first mission, then stood: the base stays put while it holds.
    end = np.array(states[-1])
    assert end[BASE_POS][0] == pytest.approx(0.25, abs=0.03)
    held = np.array(states[-30:])
    assert np.ptp(held[:, BASE_POS], axis=0).max() < 0.005
    assert max(tilt_deg(x) for x in states) < 3.0
    # The next plan comes: the walk goes on from where it stood.
    planner.send(plan_references(second, topology=info.topology, params=info.params))
    states = run(servo, servo.context.get_time() + (second.end_time - second.start_time) + 0.5, planner,
                 lambda t: t)
    assert not servo.player_state().holding and servo.player_state().late_holds == 1
    assert np.array(states[-1])[BASE_POS][0] == pytest.approx(0.5, abs=0.03)
    assert servo.report()["interface"]["safe_stops"] == 0
    assert planner.servo and not planner.servo[-1].safe_stop and planner.servo[-1].late_holds == 1


def test_a_silent_planner_latches_a_safe_stop_with_its_reason(walk_flat):
    scenario, info, first, _ = walk_flat
    lcm = DrakeLcm("memq://")
    config = HardwareConfig(planner_timeout=0.2)
    servo = Servo(scenario=scenario, lcm=lcm, config=config, with_driver=True)
    planner = FakePlanner(lcm, config)
    servo.simulator.Initialize()
    planner.send(plan_references(first, topology=info.topology, params=info.params))
    run(servo, 1.0, planner, lambda t: t if t < 0.78 else None)  # silent from 0.8 s on
    link = servo.interface.watchdog(servo.context)
    assert link.latched and link.reason.startswith("planner silent for ") and "timeout 0.2 s" in link.reason
    assert 0.95 < link.latched_time < 1.05
    report = servo.report()
    assert report["safe_stop"].startswith(f"at {link.latched_time:.3f} s on the servo: planner silent")
    servo.simulator.AdvanceTo(servo.context.get_time() + 0.01)  # its next messages say so
    assert planner.servo[-1].safe_stop and "planner silent" in planner.servo[-1].reason


def test_a_planning_process_that_exits_latches_a_safe_stop(walk_flat):
    scenario, *_ = walk_flat
    servo = Servo(scenario=scenario, lcm=DrakeLcm("memq://"), with_driver=True)
    servo.simulator.Initialize()
    servo.simulator.AdvanceTo(0.1)
    servo._sync_safe_stop(os.getppid())
    assert not servo.interface.watchdog(servo.context).latched
    gone = os.getppid() + 1000003
    servo._sync_safe_stop(gone)
    link = servo.interface.watchdog(servo.context)
    assert link.latched and link.reason == f"planner process {gone} exited"


def test_a_standing_row_carries_the_weight():
    row = standing_row(np.zeros(18), 100.0)
    assert row[36:54].reshape(6, 3)[:, 2].tolist() == [100.0] * 6 and math.isclose(row[54:].sum(), 6)


def test_a_table_sent_a_second_at_a_time_is_the_whole_table(walk_flat):
    scenario, info, plan, _ = walk_flat
    table = plan_references(plan, topology=info.topology, params=info.params)
    chunks = [decode_table(encode_table(c, sequence=k, utime=0))[1] for k, c in enumerate(table_chunks(table, 50))]
    assert len(chunks) == math.ceil(len(table.rows) / 50) > 2
    merged = ReferenceTable(start_time=0.0, period=table.period, rows=standing_row(np.zeros(18), 1.0)[None])
    for chunk in chunks:
        merged = merged.merged(chunk)
    assert np.array_equal(merged.after(table.start_time).rows, table.rows)


def test_real_time_scheduling_is_undone_when_its_block_ends():
    # A command run in a test's own process (main([...])) must not leave it real-time: its
    # children (a browser) would inherit SCHED_FIFO and starve one another.
    from qz_drake.errors import QzError
    from qz_drake.hardware.scheduling import realtime_priority

    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    with realtime_priority(10) as got:
        assert got == "SCHED_FIFO 10" or got.startswith("normal: SCHED_FIFO refused")
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before
    with pytest.raises(QzError, match="--realtime-priority = 100"):
        with realtime_priority(100):
            pass


def test_the_collector_leaves_the_setup_alone_and_times_what_the_loop_makes():
    # What the setup made (pydrake's modules, the diagram) is frozen out of every collection,
    # so that none walks it in the control loop; cycles the loop makes are still collected,
    # each collection timed; the freeze ends with the block (a test's own process).
    import gc
    import weakref

    from qz_drake.hardware.scheduling import steady_collector

    class Node:
        pass

    assert gc.get_freeze_count() == 0
    with steady_collector() as collector:
        collector.start()
        frozen = gc.get_freeze_count()
        assert frozen > 1000
        loop = Node()
        loop.me = loop  # a cycle made in the loop
        alive = weakref.ref(loop)
        del loop
        gc.collect()
        assert alive() is None and gc.get_freeze_count() == frozen
        summary = collector.summary()
        assert summary["gc_collections"] >= 1 and summary["gc_longest_pause_ms"] > 0
        assert summary["gc_pause_total_ms"] >= summary["gc_longest_pause_ms"]
    assert gc.get_freeze_count() == 0 and collector._callback not in gc.callbacks


def test_the_simulated_robot_runs_at_a_nice_level_that_is_undone_when_its_block_ends():
    # qz robot-sim's physics takes most of a core: it runs under normal scheduling at nice -20
    # (docs/hardware.md, why not SCHED_FIFO), and a test's own process gets its level back.
    from qz_drake.errors import QzError
    from qz_drake.hardware.scheduling import nice_level

    before = os.getpriority(os.PRIO_PROCESS, 0)
    with nice_level(-20) as got:
        now = os.getpriority(os.PRIO_PROCESS, 0)
        assert (got == "normal, nice -20" and now == -20) or ("refused" in got and now == before)
    assert os.getpriority(os.PRIO_PROCESS, 0) == before
    for bad in (-21, 20, 1.5):
        with pytest.raises(QzError, match=f"--nice = {bad}"):
            with nice_level(bad):
                pass


def test_every_thread_of_the_simulated_robot_runs_at_its_nice_level():
    """A nice level is a thread's on Linux: a thread started before the level was set (numpy's
    OpenBLAS pool, a helper) kept nice 0; with the other core busy the simulated robot's
    statuses stopped for 57-65 ms then, 14-31 ms with every thread set (session 54's busy
    demo walks, two before and three after)."""
    import threading

    from qz_drake.hardware.scheduling import nice_level

    stop = threading.Event()
    helper = threading.Thread(target=stop.wait)
    helper.start()
    try:
        tid = helper.native_id
        before = os.getpriority(os.PRIO_PROCESS, tid)
        with nice_level(-5) as got:
            if "refused" not in got:
                assert os.getpriority(os.PRIO_PROCESS, tid) == -5 == os.getpriority(os.PRIO_PROCESS, 0)
        assert os.getpriority(os.PRIO_PROCESS, tid) == before
    finally:
        stop.set()
        helper.join()
