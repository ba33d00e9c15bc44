"""Ipopt's progress, iteration by iteration, in the BLC solves of stored capability episodes
re-run with the current code: whether a solve that will run out of the trials' 30-iteration
budget can be told early from one that will converge.

    python benchmarks/blc_iteration_log.py EPISODES KEY OUT.jsonl

EPISODES episodes of data/capability_episodes drawn as a recertification draws them (key KEY),
two spawned workers; one JSON line per episode with every solve's status, iterations, time and
per-iteration (iteration, inf_pr, inf_du, mu, alg_mod, seconds, line-search trials).
"""
import json, sys, time
from multiprocessing import get_context

def work(spec):
    from qz_drake.trajopt import ipopt_mumps
    from qz_drake.capability.trials import TrialConfig
    from qz_drake.capability.episodes import run_episode
    orig = ipopt_mumps.solve
    log = []
    def intermediate(self, alg_mod, iter_count, obj, inf_pr, inf_du, mu, d_norm, reg, alpha_du, alpha_pr, ls):
        self.iterations = int(iter_count)
        self._log.append((int(iter_count), float(inf_pr), float(inf_du), float(mu), int(alg_mod), time.perf_counter() - self._t0, int(ls)))
        return True
    ipopt_mumps.ProgramNlp.intermediate = intermediate
    init = ipopt_mumps.ProgramNlp.__init__
    def init2(self, *a, **k):
        init(self, *a, **k); self._log = []; self._t0 = time.perf_counter(); log.append(self._log)
    ipopt_mumps.ProgramNlp.__init__ = init2
    solves = []
    def s(*a, **k):
        r = orig(*a, **k)
        solves.append({"status": r.status, "iterations": r.iterations, "time": r.solve_time, "log": log[-1]})
        return r
    ipopt_mumps.solve = s
    import qz_drake.trajopt.solver as S
    S.ipopt_mumps.solve = s
    records = run_episode(spec, TrialConfig())
    return spec.index, solves, [(r.get("status"), bool(r.get("success")), bool(r.get("blc_success")), r.get("reason")) for r in records]

if __name__ == "__main__":
    from qz_drake.capability.collect import _episode_sample
    from qz_drake.capability.dataset import load_records, read_manifest
    m = read_manifest("data/capability_episodes")  # the shipped episode dataset
    arrays, _ = load_records("data/capability_episodes")
    specs, stored = _episode_sample(arrays, int(sys.argv[1]), sys.argv[2], int(m["seed"]))
    with get_context("spawn").Pool(2, maxtasksperchild=10) as pool, open(sys.argv[3], "w") as out:
        for idx, solves, recs in pool.imap_unordered(work, specs):
            out.write(json.dumps({"episode": idx, "solves": solves, "records": recs}) + "\n"); out.flush()
