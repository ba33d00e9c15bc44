"""StatusPacer: the hardware interface keeps time with the robot's statuses.

Against a driver in another process (``qz robot-sim``, the robot), the interface's simulator
and the driver each keep their own time, and the phase between their periods is whatever
their start times made it. The interface reads a status once a period and the driver takes
the newest command once a period, so for some phases a command missed the driver's deadline
by a fraction of a period and was applied one period late: in two-process walks on this
machine the commands then answered statuses two periods old instead of one (4 of 6 runs at
one, 2 at two) and the joint PD, closed over the link in torque mode, tracked to 0.02 rad RMS
instead of 0.003; a whole walk_flat with such a phase missed its target by 0.45 m. So the
interface waits, just before it reads, until the status after the one it read last has come,
as a robot's control loop that blocks on the robot's state does; it then answers each status
at once, whatever the phase. In the lockstep ``memq://`` diagram the status is always there
already, and no pacer is added.

While no status comes, a wait ends one and a half of the driver's periods (measured on this
machine's clock from the statuses so far) after the newest status, and one period later for
each further read, so that the interface's time keeps running at the robot's rate and its
watchdog finds a stale link after the same time budget.

A simulator paced to real time (``Simulator.set_target_realtime_rate``, as ``qz simulate``
does) must never have to wait for its schedule: it would then read at the phase of that
schedule again. The interface therefore starts a few periods behind it, reading every other
status for its first reads, and never gets ahead of the driver by more than it was: a read
after a status that came later than the wait allowed (the interface's time then ran a period
ahead) waits for two statuses. Both show in the watchdog's ``missed`` counter.
"""

from __future__ import annotations

import dataclasses
import math
import time

from pydrake.common.value import AbstractValue
from pydrake.lcm import DrakeLcm
from pydrake.systems.framework import LeafSystem
from pydrake.systems.lcm import LcmSubscriberSystem

from qz_drake.hardware.watchdog import INTAKE_LEAD, LinkState

# Before the first status a read waits this long for it, and a wait lasts this long while the
# driver's pace is unknown: short, so that safe-stop commands keep reaching a driver that is
# already there, and so that an unpaced simulator does not race ahead of the robot. [s]
FIRST_WAIT = 0.01
# Reads after the first status that wait for two statuses, putting the interface as many
# periods behind the schedule of a paced simulator (20 ms of the robot's time, standing; a
# command still goes out every other period of the driver's, well within its budget).
LAG_READS = 10
# A status is awaited until this many of the driver's periods after the newest: late enough
# for its jitter, early enough that the interface's time keeps pace in an outage.
WAIT_PERIODS = 1.5


@dataclasses.dataclass(frozen=True)
class PacerState:
    """What StatusPacer knows of the statuses' arrivals (this machine's clock)."""

    # Statuses the subscriber had received when the interface last read.
    seen: int = 0
    # The count and wall time [s] at the first status seen, and at the newest.
    first_count: int = 0
    first_wall: float = math.nan
    last_count: int = 0
    last_wall: float = math.nan
    # Reads since the newest status without a new one.
    periods_without: int = 0
    # Reads left that wait for two statuses (LAG_READS).
    lagging: int = LAG_READS
    # The least lead of the interface's time over the driver's when it took a status in (its
    # time then minus the status's): it answered at once. [s]
    least_lead: float = math.inf

    def __deepcopy__(self, memo):  # immutable: Drake's state copies may share it
        return self

    def driver_period(self) -> float:
        """Wall time between two statuses, from those so far; FIRST_WAIT while unknown. [s]"""
        if self.last_count - self.first_count < 2:
            return FIRST_WAIT
        return (self.last_wall - self.first_wall) / (self.last_count - self.first_count)


class StatusPacer(LeafSystem):
    """Waits, before each status read of the interface, for the next status (see module doc).

    .. pydrake_system::

        name: StatusPacer
        input_ports:
        - watchdog

    It pumps ``lcm`` until ``subscriber`` has received a message it had not when the interface
    last read (two, to fall back), or until the wait's deadline; the message then reaches the
    interface through the subscriber as any other. ``watchdog`` is the interface's LinkState:
    when and with what sender time it took the newest status in.

    Args:
        lcm: the interface's LCM instance.
        subscriber: the interface's LcmSubscriberSystem of qz_status.
        period: the control period. [s]
        read_phase: when in the period the interface reads its status (fraction of a period).
    """

    def __init__(self, *, lcm: DrakeLcm, subscriber: LcmSubscriberSystem, period: float, read_phase: float):
        super().__init__()
        self._lcm = lcm
        self._subscriber = subscriber
        self._period = period
        self._watchdog = self.DeclareAbstractInputPort("watchdog", AbstractValue.Make(LinkState()))
        self._pace = self.DeclareAbstractState(AbstractValue.Make(PacerState()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, (read_phase - INTAKE_LEAD) * period, self._wait)

    def pacer_state(self, context) -> PacerState:
        return context.get_abstract_state(self._pace).get_value()

    def _received(self) -> int:
        return self._subscriber.WaitForMessage(-1)  # (returns at once: every count exceeds -1)

    def _pump_until(self, done, deadline: float) -> int:
        """Pumps the LCM until done(count of statuses received) or the wall clock's deadline."""
        count = self._received()
        while not done(count) and (left := deadline - time.monotonic()) > 0:
            self._lcm.HandleSubscriptions(max(1, math.ceil(left * 1e3)))
            count = self._received()
        return count

    def _wait(self, context, state):
        s: PacerState = context.get_abstract_state(self._pace).get_value()
        if s.seen == 0:
            count = self._pump_until(lambda count: count > 0, time.monotonic() + FIRST_WAIT)
            if count == 0:  # no status yet: the robot is not there
                return
            now = time.monotonic()
            s = PacerState(seen=count, first_count=count, first_wall=now, last_count=count, last_wall=now)
        else:
            link: LinkState = self._watchdog.Eval(context)
            lead = link.received_time - link.utime * 1e-6 if link.armed else math.inf
            ahead = lead > s.least_lead + 0.5 * self._period
            step = 2 if s.lagging or ahead else 1
            deadline = s.last_wall + (s.periods_without + step - 1 + WAIT_PERIODS) * s.driver_period()
            count = self._pump_until(lambda count: count >= s.seen + step, deadline)
            s = dataclasses.replace(s, least_lead=min(s.least_lead, lead))
            if count > s.seen:
                s = dataclasses.replace(s, seen=count, last_count=count, last_wall=time.monotonic(),
                                        periods_without=0, lagging=max(s.lagging - 1, 0))
            else:
                s = dataclasses.replace(s, periods_without=s.periods_without + 1)
        state.get_mutable_abstract_state(self._pace).set_value(s)
