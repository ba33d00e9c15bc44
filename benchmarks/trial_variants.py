"""Capability trials under simulation variants (issue 36's candidates for faster trials): the
same trial specs with the current code, the trial scenario changed per variant (the joint PD
in the plant's implicit PD actuators: station position mode; a larger plant step); each
trial's verdict, errors and times, one JSON line per (variant, trial).

    python benchmarks/trial_variants.py N VARIANT[,VARIANT...] OUT.jsonl

N trials drawn from seed 11's first 40 scenes (shuffled with rng 1), two spawned workers.
Variants: torque_2ms (the collection's), position_2ms, position_4ms, torque_3ms.
"""
import json, sys, time, random, dataclasses
from multiprocessing import get_context

VARIANTS = {
    "torque_2ms": dict(),
    "position_2ms": dict(mode="position"),
    "position_4ms": dict(mode="position", time_step=0.004),
    "torque_3ms": dict(time_step=0.003),
}

def run(args):
    variant, spec = args
    import qz_drake.capability.trials as T
    from qz_drake.config import SimulationConfig, StationConfig
    if not hasattr(T, "_original_trial_scenario"):
        T._original_trial_scenario = T.trial_scenario
    orig = T._original_trial_scenario
    opts = VARIANTS[variant]
    def patched(spec, config, criteria=None):
        sc, d = orig(spec, config, criteria)
        if "time_step" in opts:
            sc = dataclasses.replace(sc, simulation=dataclasses.replace(sc.simulation, time_step=opts["time_step"]))
        if opts.get("mode") == "position":
            sc = dataclasses.replace(sc, station=dataclasses.replace(sc.station, control_mode="position",
                                     position_kp=config.kp, position_kd=config.kd))
        return sc, d
    T.trial_scenario = patched
    t = time.perf_counter()
    r = T.run_trial(spec)
    r["wall"] = time.perf_counter() - t
    keep = ("status", "success", "reason", "blc_success", "final_xy_error_m", "max_tilt_deg", "max_joint_error_deg",
            "max_foot_slip_m", "time_sim_s", "time_solve_s", "time_total_s", "wall", "message")
    return variant, spec.trial_id, {k: r.get(k) for k in keep}

if __name__ == "__main__":
    if len(sys.argv) != 4 or not set(sys.argv[2].split(",")) <= set(VARIANTS):
        sys.exit(f"usage: trial_variants.py N VARIANT[,VARIANT...] OUT.jsonl (variants: {', '.join(VARIANTS)})")
    from qz_drake.capability.trials import trial_specs
    n = int(sys.argv[1]); variants = sys.argv[2].split(",")
    specs = trial_specs(11, 40)
    random.Random(1).shuffle(specs)
    specs = specs[:n]
    jobs = [(v, s) for s in specs for v in variants]
    out = open(sys.argv[3], "w")
    with get_context("spawn").Pool(2, maxtasksperchild=10) as pool:
        for v, tid, rec in pool.imap_unordered(run, jobs):
            out.write(json.dumps({"variant": v, "trial": tid, **{k: (float(x) if hasattr(x, "item") and not isinstance(x, str) else x) for k, x in rec.items()}}, default=str) + "\n"); out.flush()
