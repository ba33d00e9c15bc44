"""Closed-loop walking speed: real-time factor of Qingzhui walking scenarios (issue 4).

Missions planned from the measured state by the scenario's mission planner (the kinematic
tripod plan, or the BLC's optimisation), IK tracking at 200 Hz, joint PD with compensation at
every 2 ms plant step. Real-time factor including and excluding the planning time. Median of
`repeats` runs.
"""

import statistics
from pathlib import Path

from qz_drake.config import load_scenario
from qz_drake.simulation import simulate

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"
CASES = {"flat_3m": "walk_flat.yaml", "stairs_0.1m": "walk_stairs.yaml", "flat_2m_blc": "walk_flat_blc.yaml",
         "stairs_0.1m_blc": "walk_stairs_blc.yaml"}


def run(repeats: int = 3, quick: bool = False) -> dict:
    if quick:
        repeats = 1
    out = {}
    for name, file in CASES.items():
        scenario = load_scenario(SCENARIOS / file)
        factors, excluding, ok, rms = [], [], [], []
        for _ in range(repeats):
            m = simulate(scenario).metrics
            factors.append(m["realtime_factor"])
            excluding.append(m["realtime_factor_excluding_planning"])
            ok.append(m["success"])
            rms.append(m["tracking_rms_m"])
        out[name] = {"realtime_factor_median": statistics.median(factors), "realtime_factors": factors,
                     "realtime_factor_excluding_planning_median": statistics.median(excluding),
                     "blc_solves": m["blc_solves"], "blc_solve_time_s": m["blc_solve_time_s"],
                     "sim_time_s": m["sim_time_s"], "success": all(ok),
                     "tracking_rms_m_median": statistics.median(rms), "planner": m["planner"]}
    return out
