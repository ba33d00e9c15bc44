"""A prototype measured, not the BLC's code: Ipopt on the rows that can bind, adding the ones
the full check finds violated or near and solving again from where it stopped (at most five
rounds). The rows screened out are the leg-clearance rows whose value at the straight-line
guess is MARGIN or more above their bound; every other row is kept. Each bench case is solved
twice with the full program and twice screened (the best of two each).

    python benchmarks/blc_row_screening.py full|quick MARGIN

On stored capability episodes: ``python benchmarks/trial_drives.py data/capability_episodes 60
OUT.jsonl --control-mode torque --time-step 0.002 --setup blc_row_screening:use``.
"""
import sys, time, numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
from qz_drake.trajopt import ipopt_mumps as M
from qz_drake.trajopt import solver as S

class Subset:
    def __init__(self, nlp, keep):
        self.nlp, self.idx = nlp, np.flatnonzero(keep)
        self.num_vars = nlp.num_vars
        self.lower, self.upper = nlp.lower, nlp.upper
        self.constraint_lower = nlp.constraint_lower[self.idx]
        self.constraint_upper = nlp.constraint_upper[self.idx]
        self.num_constraints = len(self.idx)
        newrow = np.full(nlp.num_constraints, -1, np.int64); newrow[self.idx] = np.arange(len(self.idx))
        self.entry = keep[nlp._rows]
        self._r = newrow[nlp._rows[self.entry]].astype(np.int32); self._c = nlp._cols[self.entry]
        self.iterations = 0
    def jacobianstructure(self): return self._r, self._c
    def objective(self, x): return self.nlp.objective(x)
    def gradient(self, x): return self.nlp.gradient(x)
    def constraints(self, x): return self.nlp.constraints(x)[self.idx]
    def jacobian(self, x): return self.nlp.jacobian(x)[self.entry]
    def intermediate(self, alg, it, *a): self.iterations = int(it); return True

MARGIN = 0.1  # main() sets it from the command line
def solve(prog, x0, options=None, vectorised=(), interface="c"):
    clock = time.perf_counter()
    nlp = M.ProgramNlp(prog, vectorised)
    x = np.asarray(x0, float).copy()
    cl, cu = nlp.constraint_lower, nlp.constraint_upper
    g = nlp.constraints(x)
    only = np.zeros(len(g), bool)
    nlin = len(list(prog.linear_equality_constraints())) + len(list(prog.linear_constraints()))
    sizes = [len(b.lower) for b in nlp.blocks]
    offs = np.cumsum([0] + sizes)
    for j, v in enumerate(vectorised):
        if v.bindings[0].evaluator().get_description().startswith("leg_clearance"):
            only[offs[nlin + j]:offs[nlin + j + 1]] = True
    keep = ~only | (np.minimum(g - cl, cu - g) < MARGIN)
    total_it, rounds = 0, 0
    while True:
        rounds += 1
        sub = Subset(nlp, keep)
        p = M._CIpopt(M._ipopt_library(), sub)
        settings = {"linear_solver": "mumps", "print_level": 0, "sb": "yes", **(options or {}), "hessian_approximation": "limited-memory"}
        for k, v in settings.items():
            if isinstance(v, (bool, np.bool_)): v = "yes" if v else "no"
            elif isinstance(v, np.integer): v = int(v)
            elif isinstance(v, np.floating): v = float(v)
            p.add_option(k, v)
        x, code, obj = p.solve(x)
        total_it += sub.iterations
        g = nlp.constraints(x)
        slack = np.minimum(g - cl, cu - g)
        add = ~keep & (slack < MARGIN / 2)
        if code not in (0, 1) or not add.any() or rounds >= 5:
            break
        keep |= ~keep & (slack < MARGIN)
    STATS.append((int(keep.sum()), len(keep), rounds))
    return M.IpoptResult(x=x, status=M.STATUS.get(code, str(code)), status_code=code, iterations=total_it, objective=obj, solve_time=time.perf_counter() - clock)

STATS = []


def use(margin: float = 0.1):
    """Makes the BLC solve screened (``trial_drives.py --setup blc_row_screening:use``);
    returns the function that undoes it."""
    global MARGIN
    MARGIN = margin
    original = M.solve
    M.solve = solve

    def undo():
        M.solve = original
    return undo


def main():
    global MARGIN
    MARGIN = float(sys.argv[2]) if len(sys.argv) > 2 else 0.1
    import bench_blc
    cases = {k: v for k, v in bench_blc.all_cases(sys.argv[1] == "quick").items()
             if "impossible" not in k and "block" not in k and "rise0.20_d2.0" not in k}
    orig = M.solve
    for name, (robot, terrain, task) in cases.items():
        out = [name]
        for label, fn in (("full", orig), ("screened", solve)):
            S.ipopt_mumps.solve = fn
            S.solve_blc(task, robot, terrain)
            STATS.clear()
            ts = []
            for _ in range(2):
                t = time.perf_counter(); s = S.solve_blc(task, robot, terrain); ts.append(time.perf_counter() - t)
            extra = f" rows {STATS[-1][0]}/{STATS[-1][1]} rounds {STATS[-1][2]}" if STATS else ""
            out.append(f"{label} {min(ts):.3f}s it {s.iterations} {'ok' if s.success else 'FAIL ' + s.reason[:60]}{extra}")
        S.ipopt_mumps.solve = orig
        print(" | ".join(out), flush=True)


if __name__ == "__main__":
    main()
