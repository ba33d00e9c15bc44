"""Runs capability trials at scale: local worker processes or Ray tasks, one writer.

The driver keeps a window of trials in flight, gathers each record as it finishes, and writes
shards itself (TrialStore). Both backends run the same pure function, ``run_trial(spec)``, so
the dataset is the same array for array whichever ran it (the measured wall times aside).

Faults: a local worker that dies in the middle of a trial (a crash in Drake, a kill) is
replaced and its trial run again, up to ``max_retries`` times, as Ray retries a task whose
worker died (``ray.remote(max_retries=...)``); a trial that still cannot finish is recorded
with status "error" and its reason, never lost and never used for training.
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing as mp
import os
import signal
import threading
import time
from multiprocessing.connection import wait

from qz_drake.capability.dataset import (CHAINED_PROTOCOLS, PROVENANCE_SETTINGS, TrialStore, fingerprints,
                                         settings_dict)
from qz_drake.capability.trials import TrialConfig, TrialSpec, run_trial, stored_trial_config, trial_specs
from qz_drake.errors import bad_value

# Recertification tolerances. On one machine trials are bit for bit reproducible; on another
# processor the same code gave the same labels with measurements 1e-10 apart (2026-12-02: 18 of
# 36 records of an earlier session's machine). Chaotic seconds of contact simulation amplify the processors' rounding: 3.6e-7 and 5.9e-5
# were the largest relative differences of two recertifications, and a walk that slipped
# (trial 1429, collected on an earlier session's machine) came out here with its final yaw
# error 0.312 against 0.286 deg and its tilt 7.242 against 7.229 deg, the same on this machine
# before and after a refactor, its label equal. Labels, reasons, iteration counts and inputs
# are compared exactly; a successful walk's measurements to 2 %, a failed one's not at all.
RECERTIFY_RTOL = 2e-2
RECERTIFY_ATOL = 1e-3
# The record fields that measure how a walk went (not its label, not its inputs).
MEASURED_FIELDS = ("final_xy_error_m", "final_yaw_error_deg", "max_tilt_deg", "max_joint_error_deg",
                   "max_foot_slip_m", "max_leg_link_force_n", "sim_time_s", "message")
# Local workers per CPU at most: each holds a Drake simulation (hundreds of MB) and more than a
# few per CPU only share the CPUs' time.
MAX_WORKERS_PER_CPU = 4
# Most trials (or episodes) one collection may plan: 50 times the paper's 18000 (1000 scenes,
# six topologies, three kinds); its specs are listed up front, and a trial takes seconds.
MAX_TRIALS = 1_000_000
# Test hook: "INDEX:FILE" makes the worker running trial INDEX kill itself once (FILE marks
# that it did), the fault the collection must survive.
CRASH_ENV = "QZ_CAPABILITY_CRASH_ONCE"


def check_workers(workers, field: str = "--workers") -> int:
    """``workers`` local worker processes: at least 1, at most MAX_WORKERS_PER_CPU per CPU of
    this machine; errors name ``field``."""
    cpus = os.cpu_count() or 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise bad_value(field, workers, "must be a whole number, at least 1")
    if workers > MAX_WORKERS_PER_CPU * cpus:
        raise bad_value(field, workers, f"more than {MAX_WORKERS_PER_CPU} per CPU (this machine has {cpus}: at "
                                        f"most {MAX_WORKERS_PER_CPU * cpus}); each worker holds a Drake simulation")
    return workers


def _maybe_crash(spec: TrialSpec) -> None:
    hook = os.environ.get(CRASH_ENV, "")
    if not hook:
        return
    index, _, marker = hook.partition(":")
    if int(index) == spec.index and marker and not os.path.exists(marker):
        open(marker, "w").close()
        os._exit(17)


def start_work(spec) -> None:
    """What every worker does before a trial or an episode: Drake's warnings quiet (Ipopt's
    "maximum iteration limit" is the trials' budget doing its job; the record says so, reason
    blc_time_limit), then the fault-injection hook."""
    import logging

    logging.getLogger("drake").setLevel(logging.ERROR)
    _maybe_crash(spec)


def execute(spec: TrialSpec, config: TrialConfig) -> dict:
    """What a worker runs: the trial, behind the fault-injection hook."""
    start_work(spec)
    return run_trial(spec, config)


@dataclasses.dataclass
class CollectionSummary:
    """What a collection run did."""

    out: str
    planned: int
    already_done: int
    ran: int
    errors: int
    invalid_starts: int
    retries: int
    wall_time_s: float


def _worker_main(conn, config, function):
    while True:
        try:
            spec = conn.recv()
        except EOFError:  # the driver is gone
            return
        if spec is None:
            return
        conn.send(function(spec, config))


@contextlib.contextmanager
def _sigint_ignored():
    """Ctrl-C ignored while a worker starts, and so in the worker for good (a process started
    with SIGINT ignored keeps it so): a terminal's Ctrl-C reaches every process of the command,
    and a worker would print its KeyboardInterrupt's traceback. The driver stops the workers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


class LocalPool:
    """Worker processes (spawned: Drake is not fork-safe) fed one spec at a time.

    ``function(spec, config) -> record`` is what each worker runs (a module-level function);
    ``crashed(spec, message, config) -> record`` makes the record of a spec whose worker died
    more than ``max_retries`` times. ``max_tasks``: a worker that has returned this many
    records is stopped and a fresh one started in its place (None: workers live as long as the
    pool); ``max_memory_mb``: so is a worker whose resident memory, read after a record, has
    reached this many megabytes (None: no limit; read from /proc, so Linux only: elsewhere only
    max_tasks applies). A Drake diagram with LeafSystems written in Python is never freed in
    the process that built it (drake#22515, #23161; measured with drake 1.51.1: a full-size
    Fig. 9 walk leaves about 200 MB behind, a capability trial 8-36 MB), so a worker that builds
    one per spec grows without bound: the decisive Fig. 9 run's two workers held 12 GB each
    after about 100 walks and the machine's 24 GB ran out.
    """

    def __init__(self, workers: int, config, max_retries: int, function=None, crashed=None,
                 max_tasks: int | None = None, max_memory_mb: float | None = None):
        if max_tasks is not None and (isinstance(max_tasks, bool) or not isinstance(max_tasks, int)
                                      or max_tasks < 1):
            raise bad_value("max_tasks", max_tasks, "must be a whole number >= 1 or None")
        if max_memory_mb is not None and (isinstance(max_memory_mb, bool) or not isinstance(max_memory_mb, (int, float))
                                          or not max_memory_mb > 0):
            raise bad_value("max_memory_mb", max_memory_mb, "must be a positive number of megabytes or None")
        self._max_memory_mb = max_memory_mb
        self._ctx = mp.get_context("spawn")
        self._config = config
        self._function = function or execute
        self._crashed = crashed or _crashed
        self._max_retries = max_retries
        self._max_tasks = max_tasks
        self._workers = [self._start() for _ in range(workers)]
        self.retries = 0
        # Workers stopped after max_tasks records and replaced by fresh ones.
        self.recycled = 0
        # The largest resident memory read of a worker after a record (MB; 0 until one is read).
        self.peak_memory_mb = 0.0

    def _start(self):
        parent, child = self._ctx.Pipe()
        process = self._ctx.Process(target=_worker_main, args=(child, self._config, self._function),
                                    daemon=True)
        with _sigint_ignored():
            process.start()
        child.close()
        return {"process": process, "conn": parent, "spec": None, "attempt": 0, "done": 0}

    def _recycle(self, i: int) -> None:
        """Stops worker i (idle, done with its max_tasks) and starts a fresh one in its place."""
        w = self._workers[i]
        try:
            w["conn"].send(None)
        except (BrokenPipeError, OSError):
            pass
        w["process"].join(timeout=30)
        if w["process"].is_alive():
            w["process"].kill()
            w["process"].join()
        w["conn"].close()
        self._workers[i] = self._start()
        self.recycled += 1

    def run(self, specs, on_record) -> None:
        try:
            self._run(specs, on_record)
        except KeyboardInterrupt:
            # The workers ignore Ctrl-C (_sigint_ignored); the ones in the middle of a trial
            # are stopped here rather than waited for.
            for w in self._workers:
                if w["spec"] is not None and w["process"].is_alive():
                    w["process"].kill()
            raise

    def _run(self, specs, on_record) -> None:
        queue = [(spec, 0) for spec in specs]
        queue.reverse()
        while queue or any(w["spec"] is not None for w in self._workers):
            for w in self._workers:
                if w["spec"] is None and queue:
                    w["spec"], w["attempt"] = queue.pop()
                    w["conn"].send(w["spec"])
            busy = [w for w in self._workers if w["spec"] is not None]
            ready = wait([w["conn"] for w in busy] + [w["process"].sentinel for w in busy])
            for i, w in enumerate(self._workers):
                if w["spec"] is None:
                    continue
                if w["conn"] in ready:
                    try:
                        record = w["conn"].recv()
                    except (EOFError, OSError):
                        record = None
                    if record is not None:
                        w["spec"] = None
                        w["done"] += 1
                        on_record(record)
                        memory = resident_memory_mb(w["process"].pid) if self._max_memory_mb is not None else None
                        if memory is not None:
                            self.peak_memory_mb = max(self.peak_memory_mb, memory)
                        if queue and ((self._max_tasks is not None and w["done"] >= self._max_tasks)
                                      or (memory is not None and memory >= self._max_memory_mb)):
                            self._recycle(i)
                        continue
                if w["process"].sentinel in ready or not w["process"].is_alive():
                    spec, attempt = w["spec"], w["attempt"]
                    code = w["process"].exitcode
                    w["conn"].close()
                    self._workers[i] = self._start()
                    if attempt < self._max_retries:
                        self.retries += 1
                        queue.append((spec, attempt + 1))
                    else:
                        on_record(self._crashed(spec, f"worker died (exit code {code}) "
                                                      f"{attempt + 1} times", self._config))

    def close(self) -> None:
        for w in self._workers:
            try:
                w["conn"].send(None)
            except (BrokenPipeError, OSError):
                pass
        for w in self._workers:
            w["process"].join(timeout=10)
            if w["process"].is_alive():
                w["process"].kill()


def resident_memory_mb(pid: int) -> float | None:
    """The resident memory of process ``pid`` in MB (VmRSS of /proc/PID/status); None where it
    cannot be read (not Linux, the process gone)."""
    try:
        with open(f"/proc/{int(pid)}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        return None
    return None


# The Ray address that starts a Ray instance on this machine for one run (RayPool), with as many
# CPUs as the run's workers, and stops it when the run ends.
LOCAL_RAY = "local"


def check_ray_address(address: str, timeout: float = 5.0) -> None:
    """Raises QzError naming --ray-address unless a Ray head answers at host:port ("auto" and
    "ray://" client addresses are left to Ray; LOCAL_RAY starts one). ray.init itself retries
    for minutes."""
    import socket

    if address in ("auto", LOCAL_RAY) or address.startswith("ray://"):
        return
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise bad_value("--ray-address", address, "expected HOST:PORT of a Ray head node")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            pass
    except OSError as e:
        raise bad_value("--ray-address", address, f"no Ray cluster reachable ({e.strerror or e})") from None


def execute_episode(spec, config: TrialConfig) -> list[dict]:
    """What a worker runs for an episode (protocol "episodes"): its records, one per mission."""
    from qz_drake.capability.episodes import run_episode

    start_work(spec)
    return run_episode(spec, config)


def _crashed_episode(spec, message: str, config: TrialConfig) -> list[dict]:
    """The error record of an episode whose worker died every time."""
    from qz_drake.capability.episodes import episode_error_record

    return [episode_error_record(spec, message)]


def execute_plan_chain(spec, config: TrialConfig) -> list[dict]:
    """What a worker runs for a plan chain (protocol "plans"): its records, one per command."""
    from qz_drake.capability.plan_chains import run_plan_chain

    start_work(spec)
    return run_plan_chain(spec, config)


def _crashed_plan_chain(spec, message: str, config: TrialConfig) -> list[dict]:
    """The error record of a plan chain whose worker died every time."""
    from qz_drake.capability.plan_chains import plan_chain_error_record

    return [plan_chain_error_record(spec, message)]


def _crashed(spec: TrialSpec, message: str, config: TrialConfig) -> dict:
    """The error record of a trial whose worker died every time."""
    from qz_drake.capability.trials import base_record

    record = base_record(spec, config)
    record.update(status="error", error=message[-400:])
    return record


# Ray binds a node to the machine's outward address, even when told 127.0.0.1, unless clusters
# are switched off (its own switch for machines without them); then the node and everything it
# starts listen on loopback only.
_RAY_CLUSTER_SWITCH = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _is_loopback(address: str) -> bool:
    import ipaddress

    host = address.removeprefix("ray://").rpartition(":")[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@contextlib.contextmanager
def _loopback_ray(ray, loopback: bool):
    """While it is open, a Ray instance started here (and the node a driver joins from here)
    listens on 127.0.0.1 only; the processes Ray starts meanwhile inherit the setting."""
    if not loopback:
        yield
        return
    constants = getattr(getattr(ray, "_private", None), "ray_constants", None)
    if not hasattr(constants, "ENABLE_RAY_CLUSTER"):  # another Ray: the environment alone
        constants = None
    saved_env = os.environ.get(_RAY_CLUSTER_SWITCH)
    saved_constant = getattr(constants, "ENABLE_RAY_CLUSTER", None)
    os.environ[_RAY_CLUSTER_SWITCH] = "0"
    if constants is not None:
        constants.ENABLE_RAY_CLUSTER = False
    try:
        yield
    finally:
        if saved_env is None:
            os.environ.pop(_RAY_CLUSTER_SWITCH, None)
        else:
            os.environ[_RAY_CLUSTER_SWITCH] = saved_env
        if constants is not None:
            constants.ENABLE_RAY_CLUSTER = saved_constant


class RayPool:
    """The same specs as Ray tasks on an existing cluster (``ray.init(address=...)``), or, with
    the address LOCAL_RAY, on a Ray instance started here with ``workers`` CPUs for this pool
    and stopped by :meth:`close`. That instance, and the node of a driver joining a head at a
    loopback address, listen on 127.0.0.1 only (Ray's default is every interface).

    ``max_calls``: a Ray worker process that has run this many specs exits and Ray starts a
    fresh one (None: workers live as long as the cluster), as LocalPool's ``max_tasks``: a
    Drake diagram built in a process stays there (see LocalPool)."""

    def __init__(self, address: str, config, max_retries: int, window: int | None = None,
                 function=None, crashed=None, max_calls: int | None = None, workers: int = 2):
        if max_calls is not None and (isinstance(max_calls, bool) or not isinstance(max_calls, int)
                                      or max_calls < 1):
            raise bad_value("max_calls", max_calls, "must be a whole number >= 1 or None")
        try:
            import ray
        except ImportError:
            raise bad_value("--ray-address", address, "Ray is not installed (pip install 'qz_drake[cluster]')") from None
        self._ray = ray
        # The fault-injection hook reaches the cluster's workers through the job's environment.
        env = {CRASH_ENV: os.environ[CRASH_ENV]} if os.environ.get(CRASH_ENV) else {}
        runtime_env = {"env_vars": env} if env else None
        if address == LOCAL_RAY:
            check_workers(workers)
        try:
            with _loopback_ray(ray, address == LOCAL_RAY or _is_loopback(address)):
                if address == LOCAL_RAY:
                    ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                             runtime_env=runtime_env)
                else:
                    ray.init(address=address, ignore_reinit_error=True, log_to_driver=False,
                             runtime_env=runtime_env)
        except Exception as e:  # ConnectionError, ValueError, RuntimeError, depending on the address
            raise bad_value("--ray-address", address, f"no Ray cluster reachable ({type(e).__name__}: "
                                                       f"{str(e).splitlines()[0] if str(e) else ''})") from None
        self._config = config
        self._crashed = crashed or _crashed
        self._remote = ray.remote(max_retries=max_retries, num_cpus=1, max_calls=max_calls or 0)(function or execute)
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self._window = window or max(2 * cpus, 2)
        self.retries = 0

    def run(self, specs, on_record) -> None:
        ray = self._ray
        pending = {}
        queue = list(specs)
        queue.reverse()
        while queue or pending:
            while queue and len(pending) < self._window:
                spec = queue.pop()
                pending[self._remote.remote(spec, self._config)] = spec
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                spec = pending.pop(ref)
                try:
                    on_record(ray.get(ref))
                except Exception as e:  # the task's worker died more than max_retries times
                    on_record(self._crashed(spec, f"{type(e).__name__}: {str(e).splitlines()[0]}", self._config))

    def close(self) -> None:
        self._ray.shutdown()


PROTOCOLS = ("moves", "episodes", "plans")
# Protocols of chained missions: a spec per scene and topology (episodes.EpisodeSpec), a record
# per mission.
CHAINED = CHAINED_PROTOCOLS


def _protocol_functions(protocol: str):
    """What a worker runs for a protocol's spec, and the record of a spec whose worker died."""
    return {"moves": (execute, _crashed), "episodes": (execute_episode, _crashed_episode),
            "plans": (execute_plan_chain, _crashed_plan_chain)}[protocol]


def collect(out, *, seed: int = 0, scenes: int = 1000, topologies=None, kinds=None,
            config: TrialConfig = TrialConfig(), workers: int = 1, ray_address: str | None = None,
            shard_size: int = 100, max_retries: int = 2, progress: bool = True,
            command: str = "", limit: int | None = None, log_every: float = 0.0,
            protocol: str = "moves") -> CollectionSummary:
    """Collects (or resumes) the trials of ``scenes`` scenes into the dataset folder ``out``.

    ``protocol`` "moves": one-move trials from a standing start (paper 000 III-B), every topology
    and kind per scene; "episodes": one episode of chained missions per scene and topology
    (capability/episodes.py, issue 37), a record per mission it set out on (its kinds are the
    commands drawn, so ``kinds`` must be left out); "plans": one plan chain per scene and
    topology, missions the BLC plans one after the other and nobody walks
    (capability/plan_chains.py: labels of the BLC alone, status ``blc_only``). ``limit`` stops
    after that many new trials, episodes or chains (the rest is left for a later resume);
    ``log_every`` > 0 prints a plain progress line on stderr at most that often (seconds).
    """
    from qz_drake.capability.patches import KINDS
    from qz_drake.robot.topology import TOPOLOGY_NAMES

    if isinstance(scenes, bool) or not isinstance(scenes, int) or scenes < 1:
        raise bad_value("--scenes", scenes, "must be a positive whole number")
    topologies = tuple(topologies or TOPOLOGY_NAMES)
    kinds = tuple(kinds or KINDS)
    for t in topologies:
        if t not in TOPOLOGY_NAMES:
            raise bad_value("--topologies", t, f"unknown topology (valid: {', '.join(TOPOLOGY_NAMES)})")
    for k in kinds:
        if k not in KINDS:
            raise bad_value("--kinds", k, f"unknown kind (valid: {', '.join(KINDS)})")
    check_workers(workers)
    if protocol not in PROTOCOLS:
        raise bad_value("--protocol", protocol, f"expected one of {', '.join(PROTOCOLS)}")
    episodes = protocol in CHAINED
    if episodes and kinds != tuple(KINDS):
        raise bad_value("--kinds", ",".join(kinds), "an episode's kinds are the commands it draws: leave "
                                                    f"--kinds out with --protocol {protocol}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise bad_value("--seed", seed, "must be a whole number >= 0 (it seeds numpy's generators)")
    # An episode per scene and topology; a trial per scene, heading, topology and kind.
    per_scene = len(topologies) * (1 if episodes else config.headings_per_scene * len(kinds))
    if scenes * per_scene > MAX_TRIALS:
        unit = _unit(protocol)
        field, value = ("--headings", config.headings_per_scene) if per_scene > MAX_TRIALS else ("--scenes", scenes)
        raise bad_value(field, value, f"{scenes} scenes x {per_scene:.3g} {unit} per scene = "
                                      f"{scenes * per_scene:.3g} {unit}; at most {MAX_TRIALS:.3g} in one collection")
    settings = settings_dict(config)
    if episodes:  # a moves dataset's settings stay as they were before episodes existed
        settings["protocol"] = protocol
        from qz_drake.capability.episodes import episode_specs

        specs = episode_specs(seed, scenes, topologies=topologies)
    else:
        specs = trial_specs(seed, scenes, topologies=topologies, kinds=kinds,
                            headings_per_scene=config.headings_per_scene)
    function, crashed = _protocol_functions(protocol)
    return collect_units(out, specs, seed=seed, settings=settings, config=config, function=function,
                         crashed=crashed, unit=_unit(protocol), workers=workers, ray_address=ray_address,
                         shard_size=shard_size, max_retries=max_retries, progress=progress, command=command,
                         limit=limit, log_every=log_every)


def collect_units(out, specs, *, seed: int, settings: dict, config: TrialConfig, function, crashed,
                  unit: str, workers: int = 1, ray_address: str | None = None, shard_size: int = 100,
                  max_retries: int = 2, progress: bool = True, command: str = "", limit: int | None = None,
                  log_every: float = 0.0) -> CollectionSummary:
    """Runs (or resumes) ``specs`` (each with a unique ``index``) into the dataset folder
    ``out``: ``function(spec, config)`` on the workers gives a spec's record or records,
    ``crashed(spec, message, config)`` the record of a spec whose worker died; ``settings``
    and the code's fingerprints are the manifest's, checked on a resume; ``unit`` names a spec
    in progress lines. :func:`collect`'s protocols and the episodes of the planners' own routes
    (qz_drake.experiments.route_episodes) run through it."""
    check_workers(workers)
    if isinstance(shard_size, bool) or not isinstance(shard_size, int) or shard_size < 1:
        raise bad_value("--shard-size", shard_size, "must be a whole number of records, at least 1")
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 0):
        raise bad_value("--limit", limit, "must be a whole number of trials, 0 or more")
    if ray_address:
        check_ray_address(ray_address)
    clock = time.perf_counter()
    parts = fingerprints(config)
    store = TrialStore(out, seed=seed, settings=settings, parts=parts, command=command)
    try:
        done = store.done_indices()
        todo = [s for s in specs if s.index not in done]
        if limit is not None:
            todo = todo[:limit]
        buffer: list[dict] = []
        counts = {"ran": 0, "errors": 0, "invalid": 0}
        monitor = _Progress(len(todo), enabled=progress, log_every=log_every, unit=unit)

        def on_record(result):
            # A trial's record, or an episode's records (its first tells how it started).
            records = result if isinstance(result, list) else [result]
            buffer.extend(records)
            counts["ran"] += 1
            counts["errors"] += records[0]["status"] == "error"
            counts["invalid"] += records[0]["status"] == "invalid"
            for record in records[1:]:
                monitor.count(record)
            monitor.update(records[0])
            if len(buffer) >= shard_size:
                store.append(buffer)
                buffer.clear()

        pool = None
        previous = _raise_on_sigterm()
        try:
            if todo:
                pool = RayPool(ray_address, config, max_retries, function=function, crashed=crashed,
                               workers=workers) \
                    if ray_address else LocalPool(min(workers, len(todo)), config, max_retries,
                                                  function=function, crashed=crashed)
                pool.run(todo, on_record)
        finally:
            # Whatever finished is kept, also when the run is interrupted.
            store.append(buffer)
            monitor.close()
            if pool is not None:
                pool.close()
            _restore_sigterm(previous)
    finally:
        store.close()  # the folder's lock
    return CollectionSummary(out=str(out), planned=len(specs), already_done=len(done), ran=counts["ran"],
                             errors=counts["errors"], invalid_starts=counts["invalid"],
                             retries=pool.retries if pool else 0,
                             wall_time_s=time.perf_counter() - clock)


def _unit(protocol: str) -> str:
    return {"moves": "trials", "episodes": "episodes", "plans": "chains"}[protocol]


def _raise_on_sigterm():
    """A SIGTERM (a session or job ending) interrupts the collection like Ctrl-C, so that the
    finished records are written before the process ends."""
    if threading.current_thread() is not threading.main_thread() or callable(signal.getsignal(signal.SIGTERM)):
        return None  # a caller's own handler (the qz command's) already interrupts

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    return signal.signal(signal.SIGTERM, interrupt)


def _restore_sigterm(previous) -> None:
    if previous is not None:
        signal.signal(signal.SIGTERM, previous)


class _Progress:
    """A rich progress bar with trials per second, ETA and the success rate so far per
    topology and kind."""

    def __init__(self, total: int, enabled: bool, log_every: float = 0.0, unit: str = "trials"):
        self.enabled = enabled and total > 0
        self.unit = unit
        self.rates: dict[tuple[str, str], list[int]] = {}
        self.log = _ProgressLog(total, log_every, self.rates, unit) if log_every > 0 and total > 0 else None
        if not self.enabled:
            return
        from rich.console import Group
        from rich.live import Live
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                   TimeElapsedColumn, TimeRemainingColumn)

        from qz_drake.progress import SPEED_PERIOD, stderr_console

        self._progress = Progress(TextColumn(unit), BarColumn(), MofNCompleteColumn(),
                                  TextColumn("{task.fields[rate]:.2f}/s"), TimeElapsedColumn(),
                                  TextColumn("ETA"), TimeRemainingColumn(), speed_estimate_period=SPEED_PERIOD)
        self._task = self._progress.add_task(unit, total=total, rate=0.0)
        self._start = time.perf_counter()
        self._group = Group
        # On stderr, as every progress display (qz_drake.progress): the summary on stdout stays JSON.
        self._live = Live(self._render(), refresh_per_second=2, transient=False, console=stderr_console())
        self._live.start()

    def _render(self):
        from rich.table import Table

        table = Table(title="planned so far (plan chains)" if self.unit == "chains" else
                      "success so far (executed trials)", show_edge=False)
        table.add_column("topology")
        kinds = sorted({k for _, k in self.rates})
        for kind in kinds:
            table.add_column(kind)
        for topology in sorted({t for t, _ in self.rates}):
            row = [topology]
            for kind in kinds:
                ok, n = self.rates.get((topology, kind), [0, 0])
                row.append(f"{ok}/{n} ({100 * ok / n:.0f} %)" if n else "-")
            table.add_row(*row)
        return self._group(self._progress, table)

    def count(self, record: dict) -> None:
        """Counts an executed record's outcome in the success rates, a plan chain's record's
        plan (blc_success: a chain walks nothing), without a step of the bar."""
        label = {"executed": "success", "blc_only": "blc_success"}.get(record["status"])
        if label is not None:
            entry = self.rates.setdefault((record["topology"], record["kind"]), [0, 0])
            entry[0] += bool(record[label])
            entry[1] += 1

    def update(self, record: dict) -> None:
        self.count(record)
        if self.log is not None:
            self.log.update()
        if not self.enabled:
            return
        elapsed = max(time.perf_counter() - self._start, 1e-9)
        done = self._progress.tasks[0].completed + 1
        self._progress.update(self._task, advance=1, rate=done / elapsed)
        self._live.update(self._render())

    def close(self) -> None:
        if self.enabled:
            self._live.stop()


class _ProgressLog:
    """One plain line on stderr at most every ``every`` seconds (a background run's log): trials
    done, rate, ETA and the success rate so far."""

    def __init__(self, total: int, every: float, rates: dict, unit: str = "trials"):
        self.total, self.every, self.rates, self.unit = total, float(every), rates, unit
        self.start = self.last = time.perf_counter()
        self.done = 0

    def update(self) -> None:
        import sys

        self.done += 1
        now = time.perf_counter()
        if now - self.last < self.every and self.done < self.total:
            return
        self.last = now
        rate = self.done / max(now - self.start, 1e-9)
        ok = sum(v[0] for v in self.rates.values())
        executed = sum(v[1] for v in self.rates.values())
        eta = (self.total - self.done) / rate if rate > 0 else float("inf")
        what = ("planned", "labelled") if self.unit == "chains" else ("success", "executed")
        success = f"{100 * ok / executed:.0f} % of {executed} {what[1]}" if executed else f"none {what[1]}"
        print(f"{self.unit} {self.done}/{self.total} ({100 * self.done / self.total:.1f} %), "
              f"{3600 * rate:.0f}/h, ETA {eta / 3600:.1f} h, {what[0]} {success}",
              file=sys.stderr, flush=True)


@dataclasses.dataclass
class Recertification:
    """What ``recertify`` found: the components whose code changed, the trials re-run and
    whether every one of them came out the same (then the manifest now names this code)."""

    dataset: str
    changed: list
    rerun: int
    identical: bool
    mismatches: list
    fingerprint_before: str
    fingerprint_after: str
    wall_time_s: float
    # Largest relative difference of a measured float between a stored and a re-run record.
    largest_relative_difference: float = 0.0
    # Mismatches that the certified code, re-run here (``reference_code``), reproduces exactly
    # as the new code does: the stored record is the processor that collected it, not the code.
    machine_differences: list = dataclasses.field(default_factory=list)
    # What was re-run: "trials" (one record each), "episodes" or "chains" (a record per mission).
    unit: str = "trials"


@dataclasses.dataclass(frozen=True)
class RecertifyHooks:
    """What recertify needs of a protocol :func:`collect` does not run (the episodes of the
    planners' routes, qz_drake.experiments.route_episodes.recertify_hooks): the settings keys
    that are not TrialConfig's (``extra``), the specs by index from the manifest's settings and
    seed (``specs``), and the worker's function and crashed-record function."""

    protocol: str
    extra: tuple
    specs: object  # (settings, seed) -> {index: spec}
    function: object
    crashed: object


def _episode_sample(arrays: dict, count: int, key: str, seed: int, specs_by_index=None, uniform: bool = False):
    """(EpisodeSpecs, episode index -> its stored records in mission order) of up to ``count``
    episodes, chosen as recertification_sample chooses trials but by each episode's last record
    (where an episode's outcome is: the first failure ends it); ``uniform``: drawn uniformly
    from the episodes without a crash instead (seeded by ``key``), as the dataset has them."""
    import numpy as np

    from qz_drake.capability.episodes import EpisodeSpec

    index = np.asarray(arrays["index"])
    order = np.lexsort((np.asarray(arrays["heading_sample"]), index))
    last = {int(index[i]): int(i) for i in order}  # each episode's last record
    first = {}
    for i in order[::-1]:
        first[int(index[i])] = int(i)
    positions = sorted(last.values())
    ends = {k: v[positions] for k, v in arrays.items()}
    if uniform:
        import hashlib

        rng = np.random.default_rng(int(hashlib.sha256(key.encode()).hexdigest()[:12], 16))
        whole = sorted(e for e in last if not any(arrays["status"][i] == "error" for i in np.flatnonzero(index == e)))
        chosen = sorted(int(e) for e in rng.choice(whole, size=min(count, len(whole)), replace=False))
    else:
        chosen = [int(ends["index"][j]) for j in recertification_sample(ends, count, key)]
    specs = [specs_by_index[e] if specs_by_index is not None else
             EpisodeSpec(seed, e, int(arrays["scene"][first[e]]), str(arrays["topology"][first[e]])) for e in chosen]
    stored = {e: [{k: v[i:i + 1] for k, v in arrays.items()} for i in order if int(index[i]) == e] for e in chosen}
    return specs, stored


def recertification_sample(arrays: dict, count: int, key: str) -> list[int]:
    """Up to ``count`` record positions, spread over every (status, kind, topology, outcome,
    scene kind) group in turn, drawn with a seed derived from ``key``: failures and successes,
    invalid starts, every kind and topology are all re-run, not only the common case."""
    import hashlib

    import numpy as np

    rng = np.random.default_rng(int(hashlib.sha256(key.encode()).hexdigest()[:12], 16))
    groups: dict = {}
    for i in range(len(arrays["index"])):
        if arrays["status"][i] == "error":
            continue  # a crash is not behaviour to compare
        g = (str(arrays["status"][i]), str(arrays["kind"][i]), str(arrays["topology"][i]),
             bool(arrays["success"][i]), str(arrays["reason"][i]), str(arrays["scene_kind"][i]))
        groups.setdefault(g, []).append(i)
    order = [rng.permutation(members).tolist() for _, members in sorted(groups.items())]
    rng.shuffle(order)
    chosen: list[int] = []
    while len(chosen) < count and any(order):
        for members in order:
            if members and len(chosen) < count:
                chosen.append(members.pop())
    return sorted(chosen)


def recertify(path, *, sample: int = 36, workers: int = 1, command: str = "",
              reference_code=None, hooks: RecertifyHooks | None = None) -> Recertification:
    """Re-runs a sample of a dataset's trials with the running code; if every re-run record is
    identical to the stored one (all fields but the wall times), the manifest is moved to this
    code's fingerprints and the certification (old and new fingerprints, the trials re-run, the
    command) is appended to its ``certifications``. Otherwise nothing is written.

    This is for changes that should not change behaviour (a refactor, a speed-up, an option
    that is off by default): trials are deterministic, so such a change reproduces every
    stored record exactly. A change that alters only trials outside the sample can pass
    unnoticed; a change meant to alter labels needs a new collection, not this.

    Trials are deterministic on one machine, not across processors: a record collected on
    another one can differ here (a BLC solve that converged at the last iteration of its
    budget there runs out of it here). With ``reference_code``, a source tree (e.g. a git
    worktree) of the code the manifest names, every mismatched trial is run again with that
    code on this machine: where it gives exactly what the new code gives, the difference is
    the machine's, not the change's; it is accepted and listed in the certification
    (``machine_differences``). The tree must have the manifest's fingerprints. An episode
    dataset's mismatched episodes are run again whole, every mission compared. ``hooks`` give
    the specs and worker of a protocol this module does not run (RecertifyHooks).
    """
    from qz_drake.capability.dataset import DatasetLock, read_manifest

    clock = time.perf_counter()
    if isinstance(sample, bool) or not isinstance(sample, int) or sample < 1:
        raise bad_value("--sample", sample, "must be a positive whole number")
    check_workers(workers)
    from pathlib import Path

    if reference_code is not None and not (Path(reference_code) / "qz_drake" / "__init__.py").is_file():
        raise bad_value("--reference-code", str(reference_code), "not a source tree with a qz_drake package")
    manifest = read_manifest(path)
    lock = DatasetLock(path, field="dataset")  # no collection may write it meanwhile
    try:
        return _recertify(path, manifest, sample, workers, command, clock, reference_code, hooks)
    finally:
        lock.release()


def _recertify(path, manifest, sample, workers, command, clock, reference_code=None,
               hooks: RecertifyHooks | None = None) -> Recertification:
    from datetime import datetime, timezone

    from qz_drake.capability.dataset import (combined_fingerprint, differing_fields, load_records,
                                             records_to_arrays, write_manifest)
    from qz_drake.capability.trials import TIME_FIELDS

    settings = dict(manifest.get("settings", {}))
    protocol = settings.pop("protocol", "moves")
    for key in PROVENANCE_SETTINGS:  # where the dataset came from, not how its trials run
        settings.pop(key, None)
    extra = {}
    routed = hooks is not None and protocol == hooks.protocol
    if routed:
        extra = {k: settings.pop(k) for k in hooks.extra if k in settings}
        if reference_code is not None:
            raise bad_value("--reference-code", str(reference_code),
                            f"a {protocol} dataset is re-run with this code only (its specs come from walks' records)")
    elif protocol not in PROTOCOLS:
        raise bad_value("dataset.settings.protocol", protocol,
                        f"expected one of {', '.join(PROTOCOLS)}" + ("; a routes dataset is recertified by `qz "
                                                                      "capability recertify`" if protocol == "routes"
                                                                      else ""))
    episodes = protocol in CHAINED
    config = stored_trial_config(settings)
    parts = fingerprints(config)
    old = manifest.get("fingerprints", {})
    changed = [k for k in sorted(set(parts) | set(old)) if parts.get(k) != old.get(k)]
    before = manifest.get("fingerprint", "")
    if not changed:
        return Recertification(str(path), [], 0, True, [], before, before,
                               time.perf_counter() - clock)
    arrays, _ = load_records(path)
    seed = int(manifest["seed"])
    key = before + combined_fingerprint(parts)
    if episodes:
        specs, stored = _episode_sample(arrays, sample, key, seed,
                                        hooks.specs({**settings, **extra}, seed) if routed else None)
    else:
        positions = recertification_sample(arrays, sample, key)
        specs = [TrialSpec(seed, int(arrays["index"][i]), int(arrays["scene"][i]),
                           int(arrays["heading_sample"][i]), str(arrays["topology"][i]),
                           str(arrays["kind"][i])) for i in positions]
        stored = {int(arrays["index"][i]): [{k: v[i:i + 1] for k, v in arrays.items()}] for i in positions}
    rerun: dict[int, list] = {}
    function, crashed = (hooks.function, hooks.crashed) if routed else _protocol_functions(protocol)
    pool = LocalPool(min(workers, len(specs)), config, 0, function, crashed) if specs else None
    try:
        if pool is not None:
            # A trial gives one record, an episode a list (one per mission).
            pool.run(specs, lambda out: rerun.__setitem__(
                int((out[0] if isinstance(out, list) else out)["index"]), out if isinstance(out, list) else [out]))
    finally:
        if pool is not None:
            pool.close()
    mismatches, largest = compare_records(stored, rerun, episodes)
    machine = []
    if mismatches and reference_code is not None:
        indices = [m["index"] for m in mismatches]
        # Every setting named, as this code reads the manifest (a field it does not name is what
        # the dataset was collected with, not the reference code's default).
        reference = _run_with_code(reference_code, [s for s in specs if s.index in indices], settings_dict(config),
                                   old, protocol=protocol)
        for m in list(mismatches):
            here = differing_fields(reference[m["index"]], records_to_arrays(rerun[m["index"]]),
                                    skip=TIME_FIELDS)
            if not here:
                mismatches.remove(m)
                machine.append(m)
    after = combined_fingerprint(parts)
    if not mismatches:
        manifest.setdefault("certifications", []).append({
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "changed": changed, "fingerprints_before": old, "fingerprints_after": parts,
            "rerun_indices": sorted(stored), "command": command,
            "float_tolerance": {"rtol": RECERTIFY_RTOL, "atol": RECERTIFY_ATOL},
            "largest_relative_difference": largest,
            **({"machine_differences": machine} if machine else {})})
        manifest["fingerprints"], manifest["fingerprint"] = parts, after
        write_manifest(path, manifest)
    return Recertification(str(path), changed, len(stored), not mismatches, mismatches, before,
                           after if not mismatches else before, time.perf_counter() - clock,
                           largest, machine, "episodes" if routed else _unit(protocol))


def compare_records(stored: dict, rerun: dict, episodes: bool) -> tuple[list, float]:
    """(mismatches, largest relative difference of a measured float) of re-run records against
    stored ones (both: index -> its records in order; stored as one-row arrays, re-run as
    record dicts): labels, reasons, iteration counts and inputs equal; measured floats equal to
    RECERTIFY_RTOL for a walk that succeeded (a failed walk's measurements are where it was
    stopped, which rounding on another processor moves: not compared)."""
    from qz_drake.capability.dataset import differing_fields, records_to_arrays
    from qz_drake.capability.trials import TIME_FIELDS

    mismatches = []
    largest = 0.0
    for index, old_records in stored.items():
        new_records = rerun[index]
        if len(new_records) != len(old_records):
            mismatches.append({"index": index, "fields": ["records"],
                               "stored": {"records": len(old_records)}, "now": {"records": len(new_records)}})
            continue
        for old_record, record in zip(old_records, new_records):
            new = records_to_arrays([record])
            skip = TIME_FIELDS + (() if bool(old_record["success"][0]) else MEASURED_FIELDS)
            fields = differing_fields(old_record, new, skip=skip, rtol=RECERTIFY_RTOL, atol=RECERTIFY_ATOL)
            largest = max(largest, _largest_relative_difference(old_record, new))
            if fields:
                mismatches.append({"index": index, "fields": fields,
                                   **({"mission": int(old_record["heading_sample"][0])} if episodes else {}),
                                   "stored": {f: _plain(old_record[f][0]) for f in fields[:4]},
                                   "now": {f: _plain(new[f][0]) for f in fields[:4]}})
                break
    return mismatches, largest


# Run by _run_with_code in a fresh interpreter whose qz_drake is the reference tree's.
_REFERENCE_SCRIPT = """
import json, sys
from pathlib import Path
import numpy as np
import qz_drake
from qz_drake.capability.dataset import fingerprints, records_to_arrays
from qz_drake.capability.trials import TrialConfig, TrialSpec, run_trial
job = json.loads(Path(sys.argv[1]).read_text())
root = Path(job["root"]).resolve()
if root not in Path(qz_drake.__file__).resolve().parents:
    sys.exit(f"--reference-code = {str(root)!r}: its qz_drake is not the one imported ({qz_drake.__file__})")
config = TrialConfig(**job["settings"])
parts = fingerprints(config)
protocol = job.get("protocol", "episodes" if job.get("episodes") else "moves")
for key in sorted(set(parts) | set(job["fingerprints"])):
    if parts.get(key) != job["fingerprints"].get(key):
        sys.exit(f"--reference-code = {str(root)!r}: its {key} fingerprint {parts.get(key)!r} is not the "
                 f"manifest's {job['fingerprints'].get(key)!r} (not the certified code)")
if protocol in ("episodes", "plans"):
    from qz_drake.capability.episodes import EpisodeSpec
    if protocol == "plans":
        from qz_drake.capability.collect import execute_plan_chain as execute_chain
    else:
        from qz_drake.capability.collect import execute_episode as execute_chain
    records = [r for spec in job["specs"] for r in execute_chain(EpisodeSpec(*spec), config)]
else:
    records = [run_trial(TrialSpec(*spec), config) for spec in job["specs"]]
np.savez(job["out"], **records_to_arrays(records))
"""


def _run_with_code(root, specs, settings: dict, fingerprints_expected: dict, protocol: str = "moves") -> dict:
    """index -> the record arrays of each spec run by the code in the source tree ``root`` (a
    fresh interpreter with ``root`` first on its path; an episode's records, one row per
    mission), after checking that the tree has the expected fingerprints. Raises a ConfigError
    naming --reference-code when it is not that code."""
    import json
    import os
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    import numpy as np

    root = Path(root)
    if not (root / "qz_drake" / "__init__.py").is_file():
        raise bad_value("--reference-code", str(root), "not a source tree with a qz_drake package")
    with tempfile.TemporaryDirectory() as tmp:
        job = {"root": str(root), "settings": settings, "fingerprints": fingerprints_expected,
               "episodes": protocol == "episodes", "protocol": protocol,
               "specs": [[s.seed, s.index, s.scene, s.topology] if protocol in CHAINED else
                         [s.seed, s.index, s.scene, s.heading_sample, s.topology, s.kind] for s in specs],
               "out": str(Path(tmp) / "reference.npz")}
        (Path(tmp) / "job.json").write_text(json.dumps(job))
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root.resolve())] + (
            [os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])))
        run = subprocess.run([sys.executable, "-c", _REFERENCE_SCRIPT, str(Path(tmp) / "job.json")],
                             capture_output=True, text=True, env=env, cwd=tmp)
        if run.returncode != 0:
            lines = (run.stderr or run.stdout).strip().splitlines() or ["exited with " + str(run.returncode)]
            message = lines[-1]
            if message.startswith("--reference-code"):
                from qz_drake.errors import ConfigError

                raise ConfigError(message)
            raise bad_value("--reference-code", str(root), f"its trials did not run ({message[:200]})")
        with np.load(job["out"], allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    index = np.asarray(arrays["index"])
    return {int(i): {k: v[index == i] for k, v in arrays.items()} for i in np.unique(index)}


def _largest_relative_difference(a: dict, b: dict) -> float:
    """Largest |x - y| / max(|x|, 1e-12) over the floating-point fields of two records (wall
    times aside); 0 where they are bit for bit equal."""
    import numpy as np

    from qz_drake.capability.trials import TIME_FIELDS

    worst = 0.0
    for key, x in a.items():
        x = np.asarray(x)
        y = np.asarray(b.get(key, x))
        if key in TIME_FIELDS or x.dtype.kind != "f" or x.shape != y.shape:
            continue
        both = np.isfinite(x) & np.isfinite(y)
        if both.any():
            d = np.abs(x[both] - y[both]) / np.maximum(np.abs(x[both]), 1e-12)
            worst = max(worst, float(d.max()))
    return worst


def _plain(value):
    import numpy as np

    value = np.asarray(value)
    return value.tolist() if value.ndim else value.item()
