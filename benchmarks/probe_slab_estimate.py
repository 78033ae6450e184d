"""The slab estimate of large runs: its error, its warning and its cost against the solve.

The 50-mass chain (T = 10) with every method at 1e-2, 1e-4, 1e-6, the 100-mass chain (T =
20) and the reaction front (N = 1000) of :mod:`dolfinode.bench.problems`: per run the scaled
error at T and the default estimate (both / tolerance), whether the default solve warned
(W) or noted that it did not estimate (note), the solve's CPU time (``estimate_global_error=
False``) and the cost of :func:`dolfinode.global_error.slab_estimate` over it (warm, minimum
of two interleaved repeats). Prints one Markdown row per run.

Usage::

    python benchmarks/probe_slab_estimate.py
"""
import time
import warnings

import numpy as np

import dolfinode as dn
from dolfinode import global_error
from dolfinode.bench import problems
from dolfinode.compile import lower

ALL = ("mcG(1)", "mcG(2)", "mcG(3)", "mdG(1)", "mdG(2)", "mdG(3)",
       "cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)")
RUNS = ((problems.mass_spring_chain, {}, ALL, (1e-2, 1e-4, 1e-6)),
        (problems.mass_spring_chain, {"n": 100, "T": 20.0}, ("mcG(1)", "mcG(2)", "cG(2)"),
         (1e-5,)),
        (problems.reaction_front, {"n": 1000}, ("mcG(1)", "mcG(2)", "cG(1)"), (1e-6,)))


def row(p, method, tol, compiled):
    """The Markdown row of one run of the problem ``p``."""
    kw = {"method": method, "tolerance": tol, "absolute_tolerance": p.atol_ratio * tol}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = dn.solve(p.ode, **kw)
    warned = any(issubclass(w.category, dn.ToleranceWarning) for w in caught)
    solve, estimate = [], []
    for _ in range(2):
        start = time.process_time()
        plain = dn.solve(p.ode, estimate_global_error=False, **kw)
        solve.append(time.process_time() - start)
        start = time.process_time()
        global_error.slab_estimate(plain, compiled)
        estimate.append(time.process_time() - start)
    error = float("nan")
    if p.final is not None:
        error = np.max(np.abs(sol(p.T) - p.final) / (p.atol_ratio + np.abs(p.final))) / tol
    found = sol.stats.get("global error estimate", float("nan")) / tol
    kind = "note" if "global error note" in sol.stats else ("W" if warned else "-")
    return (f"| {p.description} | {method} | {tol:.0e} | {error:.3g} | {found:.3g} | {kind} | "
            f"{min(solve):.3f} | {min(estimate) / min(solve):.2f} |")


def main():
    print("| problem | method | tol | error | estimate | warned | solve (s) | cost |")
    print("|---|---|---|---|---|---|---|---|")
    for make, args, methods, tolerances in RUNS:
        p = make(**args)
        compiled = lower(p.ode)
        for method in methods:
            dn.solve(p.ode, method=method, tolerance=1e-2)  # warm-up: kernels and loops
            for tol in tolerances:
                print(row(p, method, tol, compiled), flush=True)


if __name__ == "__main__":
    main()
