"""Reference tables: the IK tracker's references over a whole plan, for a servo in another process.

In the lockstep diagram the InverseKinematicsTracker holds, at each of its updates (200 Hz),
q_des, v_des, the planned stance forces and the planned contacts, and the joint PD reads them
at every plant step. On the robot the planning process (the BLC, the TLC, the tracker) must
never stand between a status and its command, so it sends the servo these references ahead,
one table per plan, solved when the plan is made (the tracker's references are a function of
the plan and the time only). The table is made by the tracker itself, stepped alone over the
plan, so the servo reads exactly what the tracker would hold at each update.

A table's rows are the tracker's update times k * period from the first at or after the plan's
start to the first after its end (where v_des is zero: the plan's end stance, held as long as
no later plan takes over).
"""

from __future__ import annotations

import dataclasses
import math
import struct

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource

from qz_drake.errors import bad_value
from qz_drake.hardware.qz_lcm import qz_reference
from qz_drake.robot.params import DEFAULT_PARAMS, NUM_JOINTS, NUM_LEGS, QingzhuiParams
from qz_drake.robot.topology import Topology
from qz_drake.systems.ik_tracker import InverseKinematicsTracker

# A row: q_des (18), v_des (18), foot forces (6 x 3, world), contact (6).
Q_DES = slice(0, NUM_JOINTS)
V_DES = slice(NUM_JOINTS, 2 * NUM_JOINTS)
DESIRED_STATE = slice(0, 2 * NUM_JOINTS)
FORCES = slice(2 * NUM_JOINTS, 2 * NUM_JOINTS + 3 * NUM_LEGS)
CONTACT = slice(FORCES.stop, FORCES.stop + NUM_LEGS)
ROW_SIZE = CONTACT.stop
# The most rows one table carries: 60 s of a plan at 200 Hz (a mission is a few seconds; a
# longer plan is cut, and its end stance held, rather than sent as a message of megabytes).
MAX_ROWS = 12000
# qz_reference's encoding (lcm-gen's): the type's fingerprint, then utime, sequence, start_time,
# period, num_rows and row_size, big-endian, then the rows' doubles one row after the other.
_HEADER = struct.Struct(">8sqqddii")
# Times within this of a row's time read that row (the plan clock and the rows are sums of
# periods, which differ in the last bits). [s]
_TIME_SLACK = 1e-9


@dataclasses.dataclass(frozen=True)
class ReferenceTable:
    """Rows of references at start_time + k * period; immutable (kept in a Drake abstract state)."""

    start_time: float
    period: float
    rows: np.ndarray  # (n, ROW_SIZE)

    def __deepcopy__(self, memo):
        return self

    @property
    def end_time(self) -> float:
        """The last row's time. [s]"""
        return self.start_time + (len(self.rows) - 1) * self.period

    def row_at(self, t: float) -> np.ndarray:
        """The row in force at plan time t: the newest at or before t (the first before the
        table starts, the last after it ends), as the tracker's held references."""
        k = math.floor((t - self.start_time) / self.period + _TIME_SLACK)
        return self.rows[min(max(k, 0), len(self.rows) - 1)]

    def merged(self, newer: ReferenceTable) -> ReferenceTable:
        """This table's rows before ``newer`` starts, then ``newer``'s (a plan takes over at its
        start); the periods must agree."""
        if not math.isclose(newer.period, self.period, rel_tol=1e-12):
            raise bad_value("qz_reference.period", newer.period, f"differs from the table's {self.period}")
        keep = math.ceil((newer.start_time - self.start_time) / self.period - _TIME_SLACK)
        if keep <= 0:
            return newer
        if keep > len(self.rows):  # a gap: the last row is held until the newer table starts
            gap = np.repeat(self.rows[-1:], keep - len(self.rows), axis=0)
            rows = np.concatenate([self.rows, gap, newer.rows])
        else:
            rows = np.concatenate([self.rows[:keep], newer.rows])
        return ReferenceTable(start_time=self.start_time, period=self.period, rows=rows)

    def after(self, t: float) -> ReferenceTable:
        """The rows from the one in force at t on (what a servo still needs at plan time t)."""
        k = math.floor((t - self.start_time) / self.period + _TIME_SLACK)
        k = min(max(k, 0), len(self.rows) - 1)
        if k == 0:
            return self
        return ReferenceTable(start_time=self.start_time + k * self.period, period=self.period,
                              rows=self.rows[k:])


def standing_row(q: np.ndarray, weight_per_foot: float) -> np.ndarray:
    """A reference row that holds the joint angles q, every foot carrying its share of the weight."""
    row = np.zeros(ROW_SIZE)
    row[Q_DES] = q
    row[FORCES] = np.tile([0.0, 0.0, weight_per_foot], NUM_LEGS)
    row[CONTACT] = 1.0
    return row


def plan_references(plan, *, topology: Topology, params: QingzhuiParams = DEFAULT_PARAMS,
                    rate: float = 200.0) -> ReferenceTable:
    """The references an InverseKinematicsTracker at ``rate`` holds over ``plan``: its updates
    from the first at or after plan.start_time to the first after plan.end_time."""
    period = 1.0 / rate
    first = math.ceil(plan.start_time / period - _TIME_SLACK)
    last = math.floor(plan.end_time / period + _TIME_SLACK) + 1
    if last - first + 1 > MAX_ROWS:
        last = first + MAX_ROWS - 1
    builder = DiagramBuilder()
    tracker = builder.AddSystem(InverseKinematicsTracker(topology=topology, params=params, rate=rate))
    source = builder.AddSystem(ConstantValueSource(AbstractValue.Make(plan)))
    builder.Connect(source.get_output_port(), tracker.GetInputPort("trajectory"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    context.SetTime(first * period)
    tracker_context = tracker.GetMyContextFromRoot(context)
    rows = np.empty((last - first + 1, ROW_SIZE))
    simulator.Initialize()
    for i, k in enumerate(range(first, last + 1)):
        # Between two updates: the update at k * period (made at the start of the step after
        # that time, as the lockstep tracker's) is in, the next is not.
        simulator.AdvanceTo((k + 0.5) * period)
        rows[i] = tracker_context.get_discrete_state(0).get_value()
    return ReferenceTable(start_time=first * period, period=period, rows=rows)


def encode_table(table: ReferenceTable, *, sequence: int, utime: int) -> bytes:
    """The table as a qz_reference message (the bytes lcm-gen's encoder writes, in one copy)."""
    rows = np.ascontiguousarray(table.rows, dtype=">f8")
    header = _HEADER.pack(qz_reference._get_packed_fingerprint(), int(utime), int(sequence),
                          float(table.start_time), float(table.period), rows.shape[0], ROW_SIZE)
    return header + rows.tobytes()


def table_chunks(table: ReferenceTable, rows: int = 200) -> list[ReferenceTable]:
    """The table as consecutive tables of at most ``rows`` rows (one second at 200 Hz): sent one
    after the other, each takes over where the one before ends, and no single message holds
    a servo's link for long."""
    return [ReferenceTable(start_time=table.start_time + k * table.period, period=table.period,
                           rows=table.rows[k:k + rows]) for k in range(0, len(table.rows), rows)]


def decode_table(data: bytes) -> tuple[qz_reference, ReferenceTable]:
    """The message (its rows left empty) and its table; ValueError naming the field for a
    malformed one. The rows are read as one array from the encoded bytes: lcm-gen's decoder
    takes them a row at a time (8 ms for a 6 s plan), time the servo has not got in a period."""
    if len(data) < _HEADER.size:
        raise ValueError(f"qz_reference: {len(data)} bytes, shorter than its header")
    fingerprint, utime, sequence, start_time, period, num_rows, row_size = _HEADER.unpack_from(data)
    if fingerprint != qz_reference._get_packed_fingerprint():
        raise ValueError("qz_reference: not a qz_reference message (its fingerprint differs)")
    if row_size != ROW_SIZE:
        raise ValueError(f"qz_reference.row_size = {row_size}: expected {ROW_SIZE}")
    if not 0 < num_rows <= MAX_ROWS:
        raise ValueError(f"qz_reference.num_rows = {num_rows}: expected 1 to {MAX_ROWS}")
    if not (math.isfinite(period) and period > 0):
        raise ValueError(f"qz_reference.period = {period}: expected a positive period")
    if not math.isfinite(start_time):
        raise ValueError(f"qz_reference.start_time = {start_time}: expected a finite time")
    if len(data) != _HEADER.size + 8 * num_rows * row_size:
        raise ValueError(f"qz_reference: {len(data)} bytes for {num_rows} rows of {row_size}")
    rows = np.frombuffer(data, dtype=">f8", offset=_HEADER.size).astype(float).reshape(num_rows, row_size)
    if not np.all(np.isfinite(rows)):
        bad = np.argwhere(~np.isfinite(rows))[0]
        raise ValueError(f"qz_reference.rows[{bad[0]}][{bad[1]}] = {rows[tuple(bad)]}: not finite")
    m = qz_reference()
    m.utime, m.sequence, m.start_time, m.period, m.num_rows, m.row_size = (utime, sequence, start_time, period,
                                                                           num_rows, row_size)
    return m, ReferenceTable(start_time=start_time, period=period, rows=rows)
