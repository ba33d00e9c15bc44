"""The row-screening prototype (blc_row_screening.py, leg-clearance rows 0.1 m clear at the
guess screened out) on stored capability episodes: each run with the full program and
screened, side by side in two workers; missions whose outcome differs and the wall time.

    python benchmarks/blc_row_screening_episodes.py EPISODES
"""
import json, sys, time
from multiprocessing import get_context
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))

def work(job):
    variant, spec = job
    import blc_row_screening as R
    from qz_drake.trajopt import solver as S
    from qz_drake.capability.trials import TrialConfig
    from qz_drake.capability.episodes import run_episode
    if variant == "screened":
        R.MARGIN = 0.1
        S.ipopt_mumps.solve = R.solve
    t = time.perf_counter()
    recs = run_episode(spec, TrialConfig())
    wall = time.perf_counter() - t
    out = []
    for r in recs:
        st = r.get("status")
        out.append(st if st != "executed" else ("walked" if r.get("success") else ("failed" if r.get("blc_success") else "no_plan")))
    return variant, spec.index, wall, out, 0.0

if __name__ == "__main__":
    from qz_drake.capability.collect import _episode_sample
    from qz_drake.capability.dataset import load_records, read_manifest
    m = read_manifest("data/capability_episodes")
    arrays, _ = load_records("data/capability_episodes")
    specs, stored = _episode_sample(arrays, int(sys.argv[1]), "trial_drives", int(m["seed"]))
    jobs = [(v, s) for s in specs for v in ("full", "screened")]
    res = {}
    with get_context("spawn").Pool(2, maxtasksperchild=10) as pool:
        for v, idx, wall, out, solve in pool.imap_unordered(work, jobs):
            res[(idx, v)] = (wall, out, solve)
    same = total = 0; changes = []
    for s in specs:
        a, b = res[(s.index, "full")][1], res[(s.index, "screened")][1]
        for k, (x, y) in enumerate(zip(a, b)):
            total += 1; same += x == y
            if x != y: changes.append((s.index, k, x, y))
    wf = sum(res[(s.index, "full")][0] for s in specs); ws = sum(res[(s.index, "screened")][0] for s in specs)
    sf = sum(res[(s.index, "full")][2] for s in specs); ss = sum(res[(s.index, "screened")][2] for s in specs)
    print(f"missions compared {total}, same outcome {same}; changes {changes}")
    print(f"episode wall {wf:.1f} -> {ws:.1f} s ({ws/wf:.3f})")
