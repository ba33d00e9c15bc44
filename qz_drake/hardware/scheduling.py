"""Real-time scheduling for the processes that stand in for the robot's control loop.

A robot's servo loop runs under a real-time policy (ros2_control's controller manager and
Drake's own hardware drivers ask for SCHED_FIFO), so that planning, logging or a browser on
the same computer never hold a command back. On Linux a process may ask for it with
``sched_setscheduler`` where it is privileged (root, CAP_SYS_NICE, or an rtprio limit); the
kernel keeps 5 % of each second for the other processes whatever a real-time one does
(``sched_rt_runtime_us``). A process that waits for its messages (``qz servo``, ``qz
robot-sim``, ``qz lcm-relay``) takes only what it uses, so the planner keeps the rest.
"""

from __future__ import annotations

import contextlib
import os

from qz_drake.errors import bad_value

# The SCHED_FIFO priority asked for by default: above every normal process, below the
# kernel's own threads (which run at 50 and above on a PREEMPT_RT kernel).
DEFAULT_PRIORITY = 40


def check_priority(priority: int, field: str = "--realtime-priority") -> int:
    """The priority, or QzError naming ``field`` for one outside 0-99."""
    if not 0 <= priority <= 99:
        raise bad_value(field, priority, "must be 0 (normal scheduling) or a SCHED_FIFO priority, 1..99")
    return priority


@contextlib.contextmanager
def realtime_priority(priority: int, field: str = "--realtime-priority"):
    """Runs this process under SCHED_FIFO at ``priority`` (1-99; 0: as it is) for the ``with``
    block and then as before, so that a command run in another program's process (a test's
    ``main([...])``) does not leave it real-time: its children (a browser, a compiler's
    threads) would inherit the policy and starve one another. Yields what it runs under, e.g.
    "SCHED_FIFO 40", or "normal: <why not>"."""
    check_priority(priority, field)
    if priority == 0:
        yield "normal"
        return
    try:
        before = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as e:  # not Linux, or not privileged: run as before
        yield f"normal: SCHED_FIFO refused ({getattr(e, 'strerror', None) or e})"
        return
    try:
        yield f"SCHED_FIFO {priority}"
    finally:
        os.sched_setscheduler(0, before[0], before[1])
