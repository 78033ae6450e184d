"""Probe the signed global error estimate of :mod:`dolfinode.global_error` (after the solve).

For each problem, method and tolerance: the scaled error at T (max_i |U_i(T) - u_i(T)| /
(atol_ratio + |u_i(T)|), as benchmarks/run_tolerance.py) over the tolerance, the estimate
scaled the same way over the tolerance, and their ratio. doc/design/global_error.md has the
results.

    python benchmarks/probe_global_error_signed.py [harmonic,chain,...] [cG(2),dG(2)] [1e-3,1e-5]
    python benchmarks/probe_global_error_signed.py --cost [hires,chain] [dG(2)] [1e-5]

``--cost``: the time of dn.solve with estimate_global_error=True over the time without, the
two interleaved, the minimum of 7 repeats each (compile excluded).
"""
import sys
import time
import warnings

import numpy as np

import dolfinode as dn
from dolfinode import global_error
from dolfinode.bench import problems

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from run_tolerance import heat_problem

PROBLEMS = {"harmonic": problems.harmonic_problem, "chain": problems.mass_spring_chain,
            "hires": problems.hires_problem, "rober": problems.rober, "vdpol": problems.vdpol,
            "pollu": problems.pollu, "heat": heat_problem}


def probe(problem, method, tol):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        sol = dn.solve(problem.ode, method=method, tolerance=tol,
                       absolute_tolerance=problem.atol_ratio * tol, maximum_steps=2_000_000)
        t1 = time.perf_counter()
    e, nu, _ = global_error.estimate(sol)
    t2 = time.perf_counter()
    scale = problem.atol_ratio + np.abs(problem.final)
    err = np.max(np.abs(sol.values[-1, -1] - problem.final) / scale)
    est = np.max(np.abs(e) / scale)
    print(f"{problem.name:9s} {method:6s} {tol:7.0e} slabs {len(sol.k):7d} "
          f"err/tol {err / tol:9.3g} est/tol {est / tol:9.3g} est/err {est / err:9.3g} nu {nu:8.2g}  solve {t1 - t0:7.3f}s "
          f"estimate {t2 - t1:7.3f}s", flush=True)


def cost(problem, method, tol, repeats=7):
    def run(estimate):
        start = time.perf_counter()
        dn.solve(problem.ode, method=method, tolerance=tol,
                 absolute_tolerance=problem.atol_ratio * tol, estimate_global_error=estimate)
        return time.perf_counter() - start

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run(True)
        times = np.array([[run(False), run(True)] for _ in range(repeats)]).min(axis=0)
    print(f"{problem.name:9s} {method:6s} {tol:7.0e} solve {times[0] * 1e3:9.3f} ms  with the "
          f"estimate {times[1] * 1e3:9.3f} ms  ratio {times[1] / times[0]:6.2f}", flush=True)


def main():
    measure = probe
    if sys.argv[1:2] == ["--cost"]:
        measure = cost
        del sys.argv[1]
    names = sys.argv[1].split(",") if len(sys.argv) > 1 else list(PROBLEMS)
    methods = sys.argv[2].split(",") if len(sys.argv) > 2 else ["cG(2)", "dG(2)"]
    tols = [float(x) for x in sys.argv[3].split(",")] if len(sys.argv) > 3 else [1e-3, 1e-5, 1e-7]
    for name in names:
        problem = PROBLEMS[name]()
        for method in methods:
            for tol in tols:
                try:
                    measure(problem, method, tol)
                except dn.SolverError as error:
                    print(f"{problem.name:9s} {method:6s} {tol:7.0e} failed: {error}"[:120])


if __name__ == "__main__":
    main()
