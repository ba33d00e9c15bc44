"""`qz bench hardware` (benchmarks/bench_hardware.py) from two source trees, side by side.

    git worktree add --detach /tmp/base COMMIT
    python benchmarks/hardware_side_by_side.py /tmp/base . REPEATS

Each run is a fresh interpreter importing qz_drake from the tree given (the editable install's
finder taken out of sys.meta_path); the trees alternate. Prints each run's latencies (median,
p99 in ms), interface overhead, tracking RMS and wall time over LCM.
"""
import sys
from tree_runs import run_in_tree
RUN = r'''
import json
import bench_hardware
r = bench_hardware.run()["walk_flat_10s"]
print(json.dumps({k: r[k] for k in ("latency", "latency_joint_pd_only", "latency_with_ik_update", "interface_overhead", "tracking_rms_lcm_m", "wall_time_lcm_s")}))
'''
if len(sys.argv) != 4:
    sys.exit("usage: hardware_side_by_side.py BASE_TREE NEW_TREE REPEATS")
for rep in range(int(sys.argv[3])):
    for label, root in (("base", sys.argv[1]), ("new", sys.argv[2])):
        d = run_in_tree(root, RUN)
        print(label, {k: (round(v["median_ms"], 3), round(v["p99_ms"], 3)) if isinstance(v, dict) else v for k, v in d.items()}, flush=True)
