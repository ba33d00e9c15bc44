"""Capability trials from two source trees, side by side: the same specs, records compared.

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/trials_side_by_side.py /tmp/base . N REPEATS

Each run is a fresh interpreter importing qz_drake from the tree given; it runs N trials of
``trial_specs(11, 40)`` shuffled with rng 2, one after the other (the last first, outside the
timing: imports and caches), and reports each trial's wall, simulation and solve time and a
hash of its verdict and measurements. The trees alternate. Prints the medians, their ratio and
whether every record is identical.
"""
import sys, statistics
from tree_runs import run_in_tree
RUN = r'''
import json, time, random, hashlib
from qz_drake.capability.trials import trial_specs, run_trial
specs = trial_specs(11, 40); random.Random(2).shuffle(specs); specs = specs[:int(sys.argv[2])]
run_trial(specs[-1])  # the process's first trial (imports, caches) outside the timing
out = []
t0 = time.perf_counter()
for s in specs[:-1]:
    t = time.perf_counter(); r = run_trial(s); w = time.perf_counter() - t
    keep = {k: r.get(k) for k in ("status", "success", "reason", "blc_success", "blc_iterations", "final_xy_error_m", "max_tilt_deg", "max_joint_error_deg", "max_foot_slip_m")}
    out.append({"wall": w, "sim": r.get("time_sim_s"), "solve": r.get("time_solve_s"), "digest": hashlib.sha256(json.dumps(keep, sort_keys=True, default=str).encode()).hexdigest()[:10], "success": bool(r.get("success"))})
print(json.dumps({"total": time.perf_counter() - t0, "trials": out}))
'''
if len(sys.argv) != 5:
    sys.exit("usage: trials_side_by_side.py BASE_TREE NEW_TREE N REPEATS")
res = {}
for rep in range(int(sys.argv[4])):
    for label, root in (("base", sys.argv[1]), ("new", sys.argv[2])):
        d = run_in_tree(root, RUN, sys.argv[3]); res.setdefault(label, []).append(d)
        print(label, round(d["total"], 1), "sim", round(sum(t["sim"] for t in d["trials"]), 1), "solve", round(sum(t["solve"] for t in d["trials"]), 1), flush=True)
b, n = res["base"], res["new"]
same = all(x["digest"] == y["digest"] for rb, rn in zip(b, n) for x, y in zip(rb["trials"], rn["trials"]))
print("records identical:", same, "walked", sum(t["success"] for t in n[0]["trials"]), "of", len(n[0]["trials"]))
tb = statistics.median(r["total"] for r in b); tn = statistics.median(r["total"] for r in n)
sb = statistics.median(sum(t["sim"] for t in r["trials"]) for r in b); sn = statistics.median(sum(t["sim"] for t in r["trials"]) for r in n)
print("total median", round(tb, 1), "->", round(tn, 1), "ratio", round(tn / tb, 3), "| sim", round(sb, 1), "->", round(sn, 1), "ratio", round(sn / sb, 3))
