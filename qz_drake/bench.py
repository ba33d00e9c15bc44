"""``qz bench SUITE``: runs a suite from the repository's benchmarks/ folder.

Benchmarks live outside the package (they are development tools, not library code); this
module finds them next to the installed source tree.
"""

from __future__ import annotations

import importlib.util
import platform
from pathlib import Path

from qz_drake.errors import ConfigError, bad_value

BENCHMARKS_DIR = Path(__file__).resolve().parents[1] / "benchmarks"

# suite -> (file in benchmarks/, function); each function takes repeats= and quick= keywords.
SUITES = {
    "sim": ("bench_sim.py", "run"),
    "walk": ("bench_walk.py", "run"),
    "blc": ("bench_blc.py", "run"),
    "capability-model": ("bench_capability_model.py", "run"),
    "astar": ("bench_planning.py", "bench_astar"),
    "costmap": ("bench_planning.py", "bench_costmap"),
    "svm": ("bench_svm.py", "run"),
    "capability": ("bench_capability.py", "run"),
    "plan": ("bench_plan.py", "run"),
    "hardware": ("bench_hardware.py", "run"),
}


def _load(file: str):
    path = BENCHMARKS_DIR / file
    if not path.is_file():
        raise ConfigError(f"suite file {path} is missing (qz bench needs a source checkout)")
    spec = importlib.util.spec_from_file_location(f"qz_bench_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def machine() -> str:
    import os

    return f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}"


def run_suite(suite: str, *, repeats: int | None = None, quick: bool = False) -> dict:
    """Runs one suite (or all) and returns its results with the machine description."""
    if suite != "all" and suite not in SUITES:
        raise bad_value("suite", suite, f"expected one of {', '.join(SUITES)}, all")
    if repeats is not None and repeats < 1:
        raise bad_value("--repeats", repeats, "must be at least 1")
    names = list(SUITES) if suite == "all" else [suite]
    results = {"machine": machine()}
    for name in names:
        file, func = SUITES[name]
        kwargs = {"quick": quick}
        if repeats is not None:
            kwargs["repeats"] = repeats
        results[name] = getattr(_load(file), func)(**kwargs)
    return results
