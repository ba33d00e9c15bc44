"""Closed-loop walking speed: real-time factor of Qingzhui walking scenarios (issue 4).

Missions planned from the measured state by the mission planner, IK tracking at 200 Hz, joint
PD with compensation at every 2 ms plant step. Until the BLC is the planner, planning is the
kinematic tripod plan, whose cost is included in the wall time (it is microseconds per
mission). Median of `repeats` runs.
"""

import statistics
from pathlib import Path

from qz_drake.config import load_scenario
from qz_drake.simulation import simulate

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
CASES = {"flat_3m": "walk_flat.yaml", "stairs_0.1m": "walk_stairs.yaml"}


def run(repeats: int = 3, quick: bool = False) -> dict:
    if quick:
        repeats = 1
    out = {}
    for name, file in CASES.items():
        scenario = load_scenario(SCENARIOS / file)
        factors, ok, rms = [], [], []
        for _ in range(repeats):
            m = simulate(scenario).metrics
            factors.append(m["realtime_factor"])
            ok.append(m["success"])
            rms.append(m["tracking_rms_m"])
        out[name] = {"realtime_factor_median": statistics.median(factors), "realtime_factors": factors,
                     "sim_time_s": m["sim_time_s"], "success": all(ok),
                     "tracking_rms_m_median": statistics.median(rms), "planner": m["planner"]}
    return out
