"""Which of a BLC program's inequality rows bind at its solution: per constraint, the rows
whose value is within 1 mm, 1 cm and 5 cm (or the constraint's own units) of a bound, for the
bench's flat 1 m / 2 s and stairs 0.15 m / 1.5 m tasks.

    python benchmarks/blc_active_rows.py
"""
import sys, numpy as np
sys.path.insert(0, "benchmarks")
import bench_blc
import qz_drake.trajopt.formulation as F
from qz_drake.trajopt import solver as S
cases = bench_blc.all_cases(False)
cap = []
init = F.BlcFormulation.__init__
def patched(self, *a, **k):
    init(self, *a, **k); cap.append(self)
F.BlcFormulation.__init__ = patched
for name in ("qz_flat_1m_2s", "qz_stairs_rise0.15_d1.5"):
    robot, terrain, task = cases[name]
    s = S.solve_blc(task, robot, terrain)
    f = cap[-1]
    x = s.x
    print(name, "rows", f.num_constraints)
    for c in f.nonlinear + f.linear:
        v = c.evaluate(x)
        lo, hi = np.broadcast_to(c.lower, v.shape), np.broadcast_to(c.upper, v.shape)
        eq = np.isclose(lo, hi)
        slack = np.minimum(v - lo, hi - v)
        ineq = ~eq
        print(f"  {c.name:18s} rows {len(v):5d} eq {int(eq.sum()):4d} ineq {int(ineq.sum()):5d}  active(<1e-3) {int((slack[ineq] < 1e-3).sum()):5d}  <1e-2 {int((slack[ineq] < 1e-2).sum()):5d}  <0.05 {int((slack[ineq] < 0.05).sum()):5d}")
