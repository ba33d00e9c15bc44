"""Real-time scheduling for the processes that stand in for the robot's control loop.

A robot's servo loop runs under a real-time policy (ros2_control's controller manager and
Drake's own hardware drivers ask for SCHED_FIFO), so that planning, logging or a browser on
the same computer never hold a command back. On Linux a process may ask for it with
``sched_setscheduler`` where it is privileged (root, CAP_SYS_NICE, or an rtprio limit); the
kernel keeps 5 % of each second for the other processes whatever a real-time one does
(``sched_rt_runtime_us``; since Linux 6.12 the fair server, which takes it 50 ms at once). A
process that waits for its messages (``qz servo``, ``qz lcm-relay``) takes only what it uses,
so the planner keeps the rest; the simulated robot, whose physics takes most of a core, runs
under normal scheduling at the lowest nice level instead (``nice_level``). Python's garbage
collector is kept out of their loops (``SteadyCollector``).
"""

from __future__ import annotations

import contextlib
import gc
import os
import threading
import time

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


# The nice level ``qz robot-sim`` asks for by default: the most CPU a normal process gets.
DEFAULT_SIMULATOR_NICE = -20


def check_nice(level: int, field: str = "--nice") -> int:
    """The nice level, or QzError naming ``field`` for one outside -20..19."""
    if isinstance(level, bool) or not isinstance(level, int) or not -20 <= level <= 19:
        raise bad_value(field, level, "must be a nice level, -20 (the most CPU) .. 19")
    return level


@contextlib.contextmanager
def nice_level(level: int, field: str = "--nice"):
    """Runs this process at nice ``level`` for the ``with`` block, then as before; yields what
    it runs at, e.g. "normal, nice -20", or "normal, nice 0 (nice -20 refused: ...)".

    For a process that computes for most of each period and is not a control loop: ``qz
    robot-sim``, whose physics step takes most of a core at real time on this machine. Under
    SCHED_FIFO such a process leaves the normal processes of its core almost no time, and since
    Linux 6.12 the kernel then runs them anyway, 50 ms of each second at once (the fair server,
    a SCHED_DEADLINE reservation that preempts every real-time task on that core): the servo
    and the relay stopped with it, and walks ended in safe stops for statuses that stopped for
    45-58 ms (a SCHED_FIFO 99 probe pinned to either core saw the same 40-52 ms stalls). At nice
    -20 it takes 88 times a nice-0 process's share and leaves the real-time class to the servo
    and the relay, which wait for their messages and use little of a core."""
    check_nice(level, field)
    # On Linux a nice level is a thread's: the process's threads started before this (numpy's
    # OpenBLAS pool, made at import) would stay at their own. Every thread of the process is
    # set, and set back.
    before = {}
    for tid in _threads():
        try:
            before[tid] = os.getpriority(os.PRIO_PROCESS, tid)
        except ProcessLookupError:  # a thread that ended meanwhile
            pass
    got = f"normal, nice {level}"
    for tid in list(before):
        try:
            os.setpriority(os.PRIO_PROCESS, tid, level)
        except ProcessLookupError:
            del before[tid]
        except OSError as e:  # lowering the nice level needs the privilege
            got = f"normal, nice {before[0]} (nice {level} refused: {e.strerror or e})"
            break
    try:
        yield got
    finally:
        for tid, was in before.items():
            try:
                os.setpriority(os.PRIO_PROCESS, tid, was)
            except OSError:  # raising it back needs no privilege; lowering it back might; gone
                pass


def _threads() -> list[int]:
    """This process's thread ids for getpriority / setpriority: the calling thread first (as 0),
    then the others /proc lists (none where there is no /proc)."""
    try:
        others = sorted(int(t) for t in os.listdir("/proc/self/task") if int(t) != threading.get_native_id())
    except OSError:  # not Linux
        others = []
    return [0, *others]


class SteadyCollector:
    """Keeps Python's cyclic garbage collector out of a real-time loop, and times what it still does.

    A full collection walks every object the interpreter tracks: in ``qz robot-sim`` (76 000
    objects: pydrake's modules, the diagram) one took 33 ms, in ``qz servo`` 27 ms, ten of the
    robot's periods and past the link's 21 ms budget, so that the other end latched a safe stop
    for statuses or commands that stopped coming. After the setup, :meth:`start` collects once
    and freezes everything alive then (``gc.freeze``: moved to a generation the collector never
    walks again, as long-running servers do), so that the collections left walk only what the
    loop itself made and keeps; each is timed (``summary``). :meth:`stop` undoes the freeze, for
    a command run inside another program's process (a test's ``main([...])``).
    """

    def __init__(self):
        self.collections = 0
        self.total = 0.0
        self.longest = 0.0
        self._began = None
        self._frozen = False

    def _callback(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._began = time.perf_counter()
        elif self._began is not None:
            pause = time.perf_counter() - self._began
            self.collections += 1
            self.total += pause
            self.longest = max(self.longest, pause)
            self._began = None

    def start(self) -> None:
        """Collects and freezes what the setup left alive; times the collections from now on."""
        if self._frozen:
            return
        gc.collect()
        gc.freeze()
        self._frozen = True
        gc.callbacks.append(self._callback)

    def stop(self) -> None:
        if not self._frozen:
            return
        gc.callbacks.remove(self._callback)
        gc.unfreeze()
        self._frozen = False

    def summary(self) -> dict:
        """The collections since :meth:`start`: how many, their sum and the longest. [ms]"""
        return {"gc_collections": self.collections, "gc_pause_total_ms": round(self.total * 1e3, 3),
                "gc_longest_pause_ms": round(self.longest * 1e3, 3)}


@contextlib.contextmanager
def steady_collector():
    """A SteadyCollector for the ``with`` block (start it once the setup is done); stopped after."""
    collector = SteadyCollector()
    try:
        yield collector
    finally:
        collector.stop()
