"""How many threads torch's operators use in this process.

torch starts one intra-op thread per core. On a machine whose other cores are busy (the
project's 2-core machine with a collection or a second walk beside it) its threads then
wait on each other and on the other work: `qz plan` on a 20 m world spent 12.7-14.9 s
planning with two threads and 4.1-4.6 s with one, with the other core busy (BENCHMARKS
"plan", session 34). So torch gets the cores that are free when the model is loaded: the
process's cores less the tasks running elsewhere at that moment (the kernel's count of runnable
tasks, /proc/loadavg), at least one. The last minute's load average was the first measure; it
counts the process's own work of a moment ago (loading, a previous plan), so `qz plan` on an
idle machine took one thread (BENCHMARKS "plan", session 41); it remains the measure where the
kernel gives no count.
``QZ_TORCH_THREADS`` sets the number instead. The shipped boosted capability model's trees
(qz_drake.capability.boosted) split a map's queries over the same number of threads.

Where the networks run: the CPU unless asked (``--device`` of the commands that plan, or
``QZ_TORCH_DEVICE`` for every model a process loads, walks and experiments included): ``cpu``,
``cuda`` / ``cuda:N`` (refused with one line where torch sees no such device) or ``auto`` (the
first CUDA device where there is one, else the CPU).
"""

from __future__ import annotations

import os

from qz_drake.errors import ConfigError, bad_value

ENV_VARIABLE = "QZ_TORCH_THREADS"
DEVICE_VARIABLE = "QZ_TORCH_DEVICE"


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


# The kernel's load line: "1-min 5-min 15-min runnable/total last-pid".
LOADAVG = "/proc/loadavg"


# A count younger than this is reused (a plan asks at each of its steps; a count costs ~3 ms). [s]
RUNNING_MAX_AGE = 0.5
_running = (-1.0, "", None)  # (when, from which file, the count)


def running_elsewhere() -> int | None:
    """Tasks running or waiting for a core now, the caller not counted: the runnable count of
    /proc/loadavg (median of three reads a millisecond apart, minus the reading thread; the
    last count if it is under RUNNING_MAX_AGE old); None where the system has no such count."""
    import time

    global _running
    now = time.monotonic()
    if _running[1] == LOADAVG and now - _running[0] < RUNNING_MAX_AGE:
        return _running[2]
    counts = []
    for _ in range(3):
        try:
            with open(LOADAVG) as f:
                counts.append(int(f.read().split()[3].split("/")[0]) - 1)
        except (OSError, IndexError, ValueError):
            counts = None
            break
        time.sleep(0.001)
    count = None if counts is None else max(0, sorted(counts)[1])
    _running = (now, LOADAVG, count)
    return count


def free_cores() -> int:
    """Cores not taken by work running elsewhere now, at least one (the last minute's load
    average where the kernel gives no runnable count)."""
    cores = available_cores()
    busy = running_elsewhere()
    if busy is None:
        try:
            busy = os.getloadavg()[0]
        except OSError:  # no load average on this system
            return cores
    return max(1, min(cores, int(cores - busy + 0.5)))


def torch_threads() -> int:
    """The intra-op threads for torch: ``QZ_TORCH_THREADS`` if set, else free_cores()."""
    value = os.environ.get(ENV_VARIABLE)
    if value is None or value == "":
        return free_cores()
    try:
        n = int(value)
    except ValueError:
        raise bad_value(ENV_VARIABLE, value, "expected a positive whole number", ConfigError) from None
    if n < 1:
        raise bad_value(ENV_VARIABLE, value, "expected a positive whole number", ConfigError)
    return n


def set_torch_threads() -> int:
    """Sets torch's intra-op threads to torch_threads() and returns the number."""
    import torch

    n = torch_threads()
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n


def set_numba_threads() -> int:
    """Sets the threads of numba's parallel loops (the map sampler, the MDP solver) to
    torch_threads(), as far as numba has them, and returns the number."""
    import numba

    n = min(torch_threads(), numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(n)
    return n


def torch_device(requested: str | None = None, field: str = "--device") -> str:
    """The torch device for capability inference: ``requested``, else ``QZ_TORCH_DEVICE``, else
    "cpu"; "auto" is "cuda" where torch sees a CUDA device, else "cpu". A device torch does
    not have is refused (ConfigError naming ``field``, or the variable)."""
    import re

    if requested is None or requested == "":
        requested, field = os.environ.get(DEVICE_VARIABLE) or "cpu", DEVICE_VARIABLE
    value = str(requested).strip().lower()
    if value == "cpu":
        return "cpu"
    if value != "auto" and not re.fullmatch(r"cuda(:\d+)?", value):
        raise bad_value(field, requested, "expected cpu, cuda, cuda:N or auto", ConfigError)
    import torch

    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if value == "auto":
        return "cuda" if count else "cpu"
    index = int(value.partition(":")[2] or 0)
    if index >= count:
        build = f"torch {torch.__version__}, " + ("a CUDA build" if torch.version.cuda else "a CPU-only build")
        raise bad_value(field, requested, f"torch sees {count} CUDA device(s) ({build})", ConfigError)
    return value
