"""The BLC against TOWR in one run: issue 36's speed aim (Qingzhui flat 1 m / 2 s warm in at
most half of TOWR's HyQ flat 1 m / 2 s, measured side by side on the same machine).

TOWR (https://github.com/ethz-adrl/towr, BSD-3) and ifopt (https://github.com/ethz-adrl/ifopt)
are not part of this repository; give their source trees (git clones) and the script builds
them (CMake, Release: -O3) against Debian's Ipopt with MUMPS, the solver TOWR uses, and
compiles ``benchmarks/towr/hyq_flat.cc`` (TOWR's HyQ on flat ground, fixed phase durations as
towr_ros leaves them, each solve a fresh problem, as TOWR's own app does; two of TOWR's gaits:
towr_ros's default overlap-walk and its trot stride, the gait of the BLC's HyQ preset):

    sudo apt-get install coinor-libipopt-dev libeigen3-dev cmake g++
    git clone https://github.com/ethz-adrl/towr /tmp/towr-src
    git clone https://github.com/ethz-adrl/ifopt /tmp/ifopt-src
    python benchmarks/towr_side_by_side.py --towr /tmp/towr-src --ifopt /tmp/ifopt-src [--rounds 3]

Each round runs TOWR's HyQ flat 1 m / 2 s and 2 m / 3 s in both gaits (``--repeats`` solves each,
median), then, in a fresh interpreter on this tree (tree_runs.run_in_tree), the BLC's Qingzhui
and HyQ flat cases of ``qz bench blc`` (``--repeats`` + 1 solves each; the first, which builds
the schedule's parts, is left out: the "warm" median). Prints every round and the medians over
the rounds with their ratios.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from tree_runs import run_in_tree

HERE = Path(__file__).resolve().parent

_OURS = r"""
import json
from bench_blc import hyq_cases, qingzhui_cases, solve_case
repeats = int(sys.argv[2])
cases = {**qingzhui_cases(True), **hyq_cases(True)}
out = {}
for name in ("qz_flat_1m_2s", "qz_flat_2m_3s", "hyq_flat_1m_2s", "hyq_flat_2m_3s"):
    r = solve_case(*cases[name], repeats=repeats + 1)
    out[name] = {"s": r["warm_solve_time_s_median"], "iterations": r["iterations"], "success": r["success"]}
print(json.dumps(out))
"""


def _run(command, cwd=None) -> None:
    try:
        result = subprocess.run(command, cwd=cwd, capture_output=True, text=True)
    except FileNotFoundError:
        sys.exit(f"{command[0]}: not found (apt-get install cmake g++ coinor-libipopt-dev libeigen3-dev)")
    if result.returncode:
        sys.exit(f"{' '.join(map(str, command))} failed:\n{(result.stdout + result.stderr)[-3000:]}")


def build(towr: Path, ifopt: Path, work: Path) -> Path:
    """ifopt and TOWR installed under work/install, the driver compiled: its path."""
    install = work / "install"
    for name, source in (("ifopt", ifopt), ("towr", towr / "towr")):
        if not (source / "CMakeLists.txt").is_file():
            sys.exit(f"--{name}: {source} has no CMakeLists.txt (expected the {name} source tree)")
        build_dir = work / f"build-{name}"
        build_dir.mkdir(parents=True, exist_ok=True)
        _run(["cmake", str(source), "-DCMAKE_BUILD_TYPE=Release", f"-DCMAKE_INSTALL_PREFIX={install}",
              f"-DCMAKE_PREFIX_PATH={install}", "-DBUILD_TESTING=OFF"], cwd=build_dir)
        _run(["make", f"-j{os.cpu_count() or 1}", "install"], cwd=build_dir)
    binary = work / "hyq_flat"
    _run(["g++", "-O3", "-DNDEBUG", "-std=c++14", str(HERE / "towr" / "hyq_flat.cc"), f"-I{install}/include",
          "-I/usr/include/eigen3", "-I/usr/include/coin", f"-L{install}/lib", "-ltowr", "-lifopt_ipopt",
          "-lifopt_core", "-lipopt", f"-Wl,-rpath,{install}/lib", "-o", str(binary)])
    return binary


def towr_case(binary: Path, repeats: int, distance: float, duration: float, gait: str) -> dict:
    run = subprocess.run([str(binary), str(repeats), str(distance), str(duration), gait], capture_output=True,
                         text=True)
    if run.returncode:
        sys.exit(f"{binary} failed:\n{run.stderr[-2000:]}")
    line = [s for s in run.stdout.splitlines() if s.startswith("{")][-1]
    result = json.loads(line)
    return {"s": result["median_s"], "iterations": result["iterations"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--towr", required=True, type=Path, help="TOWR's source tree (git clone)")
    parser.add_argument("--ifopt", required=True, type=Path, help="ifopt's source tree (git clone)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/qz_towr_build"), help="build folder")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    binary = build(args.towr.resolve(), args.ifopt.resolve(), args.work)
    rounds = []
    for r in range(args.rounds):
        entry = {f"towr_hyq_flat_{d:g}m_{t:g}s_{gait}": towr_case(binary, args.repeats, d, t, gait)
                 for gait in ("walk", "trot") for d, t in ((1.0, 2.0), (2.0, 3.0))}
        entry.update(run_in_tree(HERE.parent, _OURS, args.repeats))
        rounds.append(entry)
        print(f"round {r + 1}: " + ", ".join(f"{k} {v['s']:.3f} s ({v['iterations']} it.)" for k, v in entry.items()),
              flush=True)
    median = {k: statistics.median(e[k]["s"] for e in rounds) for k in rounds[0]}
    ratios = {f"{ours}_over_towr_{gait}": median[ours] / median[f"towr_hyq_flat_{length}_{gait}"]
              for ours, length in (("qz_flat_1m_2s", "1m_2s"), ("hyq_flat_1m_2s", "1m_2s"),
                                   ("qz_flat_2m_3s", "2m_3s"), ("hyq_flat_2m_3s", "2m_3s"))
              for gait in ("walk", "trot")}
    print(json.dumps({"rounds": rounds, "median_s": median, "ratios": ratios}))

if __name__ == "__main__":
    main()
