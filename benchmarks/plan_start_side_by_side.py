"""``qz plan`` on the 20 m long_range world from two source trees, side by side, as the shell
runs it: the start (imports, numba's first use, the model's load), the plan and, with --out,
the picture.

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/plan_start_side_by_side.py /tmp/base . --runs 5 [--bytecode]

Each run is a fresh ``python -m qz_drake.cli plan --terrain long_range --start 0,0 --goal 14,14
--json`` in the tree's folder (the folder comes first on sys.path, before the editable
install's finder), once with ``--out`` (a temporary folder, the same for both trees) and once
without. The trees alternate (base, new, base, new, ...) after one untimed run of each (numba
compiles its kernels into a fresh tree's __pycache__ there). The wall time is the child's,
start to exit, and the user time its CPU time in user mode (resource.getrusage), which a busy
machine stretches less than the wall time.

``--bytecode`` lets Python keep the trees' bytecode (PYTHONDONTWRITEBYTECODE unset, the .pyc
files under a temporary PYTHONPYCACHEPREFIX), as a shell without that variable does; without
it, the environment is passed as it is.

The runs' JSON lines must be the same in both trees but for planning_time_s (a timing), and
with --out so must plan.json (the path and the missions) but for planning_time_s. Without
--out, a tree before issue 53 draws into its own out/plan and names the picture in ``png``,
where the new one draws nothing (``png`` null): ``png`` is left out of that comparison.
Prints one JSON line per run, then per case the medians with their ratios (new / base).
"""

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMAND = ("-m", "qz_drake.cli", "plan", "--terrain", "long_range", "--start", "0,0", "--goal", "14,14", "--json")
# Timings, and (without --out) the picture that only a tree before issue 53 draws.
UNCOMPARED = {"out": ("planning_time_s",), "no_out": ("planning_time_s", "png")}


def _run(tree: str, case: str, out: Path, env: dict) -> dict:
    """One fresh ``qz plan`` in ``tree``: wall and user seconds, and what it printed and wrote."""
    command = [sys.executable, *COMMAND, *(("--out", str(out)) if case == "out" else ())]
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
    clock = time.perf_counter()
    run = subprocess.run(command, cwd=tree, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - clock
    user = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime - before
    if run.returncode not in (0, 1):  # 1: a goal no path reaches, a reported outcome
        sys.exit(f"{tree}: {' '.join(command)} exited with {run.returncode}\n{run.stderr[-3000:]}")
    line = json.loads(run.stdout.strip().splitlines()[-1])
    compared = {k: v for k, v in line.items() if k not in UNCOMPARED[case]}
    written = None
    if case == "out":
        written = json.loads((out / "plan.json").read_text())
        written.pop("planning_time_s")
    return {"wall_s": wall, "user_s": user, "exit": run.returncode, "line": compared, "plan_json": written}


def _tree_module(tree: str, env: dict) -> str:
    """The qz_drake a run in ``tree`` imports (the tree's own, not the editable install's)."""
    found = subprocess.run([sys.executable, "-c", "import qz_drake; print(qz_drake.__file__)"], cwd=tree,
                           capture_output=True, text=True, env=env, check=True).stdout.strip()
    if not found.startswith(os.path.abspath(tree)):
        sys.exit(f"{tree}: python -m imports qz_drake from {found}")
    return found


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base")
    parser.add_argument("new")
    parser.add_argument("--runs", type=int, default=5, help="timed runs per tree and case")
    parser.add_argument("--bytecode", action="store_true",
                        help="keep the bytecode (PYTHONDONTWRITEBYTECODE unset, .pyc under a temporary prefix)")
    args = parser.parse_args(argv)
    trees = {"base": os.path.abspath(args.base), "new": os.path.abspath(args.new)}
    cases = ("out", "no_out")
    with tempfile.TemporaryDirectory(prefix="plan_start_") as scratch:
        env = dict(os.environ)
        if args.bytecode:
            env.pop("PYTHONDONTWRITEBYTECODE", None)
            env["PYTHONPYCACHEPREFIX"] = os.path.join(scratch, "pycache")
        for tree in trees.values():
            _tree_module(tree, env)
        out = Path(scratch) / "plan"
        for label, tree in trees.items():
            for case in cases:
                _run(tree, case, out, env)  # numba's cache, the bytecode: what a second run finds
        runs = {(label, case): [] for label in trees for case in cases}
        for _ in range(args.runs):
            for case in cases:
                for label, tree in trees.items():
                    result = _run(tree, case, out, env)
                    print(json.dumps({"tree": label, "case": case, "wall_s": round(result["wall_s"], 3),
                                      "user_s": round(result["user_s"], 3), "exit": result["exit"]}), flush=True)
                    runs[label, case].append(result)
    summary = {}
    for case in cases:
        medians = {label: {k: statistics.median(r[k] for r in runs[label, case]) for k in ("wall_s", "user_s")}
                   for label in trees}
        every = runs["base", case] + runs["new", case]
        summary[case] = {
            "medians": medians,
            "ratio_new_over_base": {k: medians["new"][k] / medians["base"][k] for k in ("wall_s", "user_s")},
            "same_output": all((r["exit"], r["line"], r["plan_json"]) == (every[0]["exit"], every[0]["line"],
                                                                          every[0]["plan_json"]) for r in every),
        }
    print(json.dumps({"runs": args.runs, "bytecode": args.bytecode, "load_average": os.getloadavg()[0],
                      **summary}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
