"""How many threads torch's operators use in this process.

torch starts one intra-op thread per core. On a machine whose other cores are busy (the
project's 2-core machine with a collection or a second walk beside it) its threads then
wait on each other and on the other work: `qz plan` on a 20 m world spent 12.7-14.9 s
planning with two threads and 4.1-4.6 s with one, with the other core busy (BENCHMARKS
"plan", session 34). So torch gets the cores that are free when the model is loaded: the
process's cores less the load average (its own work included), at least one.
``QZ_TORCH_THREADS`` sets the number instead.
"""

from __future__ import annotations

import os

from qz_drake.errors import ConfigError, bad_value

ENV_VARIABLE = "QZ_TORCH_THREADS"


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def free_cores() -> int:
    """Cores not taken by running work (the last minute's load average), at least one."""
    cores = available_cores()
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
