"""The first step and its ramp: slabs, rejections and digits of loose mono-adaptive runs.

For the Brusselator (n = 1000) and HIRES, ROBER, VDPOL, POLLU of
:mod:`dolfinode.bench.problems`, each method solves at loose tolerances (absolute tolerance =
the problem's ratio x tolerance) and the script prints the first step, the time slabs, the
rejected steps, the failed nonlinear solves and mescd at T (doc/benchmarks/bruss.md). The
Brusselator's reference is a cG(3) solve at 1e-10.

Usage::

    python benchmarks/run_first_step.py [--problems bruss-1000,hires] [--methods "cG(2)"]
"""
import argparse
import os
from pathlib import Path

import numpy as np

import dolfinode as dn
from dolfinode.bench import problems

METHODS = ("cG(2)", "cG(3)", "dG(3)")
TOLERANCES = (1e-1, 1e-2, 1e-3, 1e-4)
PROBLEMS = {"bruss-1000": lambda: problems.brusselator(1000), "hires": problems.hires_problem,
            "rober": problems.rober, "vdpol": problems.vdpol, "pollu": problems.pollu}


def final_value(problem):
    """u(T): the published one, or a tight cG(3) solve (cached under DOLFINODE_CACHE_DIR)."""
    if problem.final is not None:
        return problem.final
    cache = Path(os.environ.get("DOLFINODE_CACHE_DIR", ".")) / f"{problem.name}-final.npy"
    if not cache.exists():
        sol = dn.solve(problem.ode, method="cG(3)", tolerance=1e-10,
                       absolute_tolerance=problem.atol_ratio * 1e-10)
        np.save(cache, sol(problem.T))
    return np.load(cache)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", default=",".join(PROBLEMS))
    parser.add_argument("--methods", default=",".join(METHODS))
    args = parser.parse_args()
    print("| problem | method | tol | first step | slabs | rejected | failed solves | mescd |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.problems.split(","):
        problem = PROBLEMS[name]()
        final = final_value(problem)
        for method in args.methods.replace("),", ");").split(";"):
            for tol in TOLERANCES:
                try:
                    sol = dn.solve(problem.ode, method=method, tolerance=tol,
                                   absolute_tolerance=problem.atol_ratio * tol)
                except dn.SolverError as error:
                    print(f"| {name} | {method} | {tol:g} | failed: {error} |")
                    continue
                _, k = sol.time_steps()
                digits = problems.mescd(sol(problem.T), final, problem.atol_ratio)
                print(f"| {name} | {method} | {tol:g} | {k[0]:.3g} | {len(k)} "
                      f"| {sol.stats['rejected steps']} "
                      f"| {sol.stats['failed nonlinear solves']} | {digits:.2f} |", flush=True)


if __name__ == "__main__":
    main()
