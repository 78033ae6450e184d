"""The slab estimate of large runs: its error, its warning and its cost against the solve.

The 50-mass chain (T = 10) with every method at 1e-2, 1e-4, 1e-6, the 100-mass chain (T =
20) and the reaction front (N = 1000) of :mod:`dolfinode.bench.problems`: per run the scaled
error at T and the default estimate (both / tolerance), whether the default solve warned
(W) or noted that it did not estimate (note), the solve's CPU time (``estimate_global_error=
False``), the cost of :func:`dolfinode.global_error.slab_estimate` over it and that of the
default solve (its estimate included) over it (warm, minimum of two interleaved repeats).
Prints one Markdown row per run.

``--stiff``: instead, the runs stiff on their slabs, where the slab estimate gives up and
the default measures the error against a tighter solve: the 50-mass chain with cubic
springs and the 300-mass chain (above MAX_DENSE components) with dG(1), dG(2) at 1e-2,
POLLU with cG(2) (reference: a dG(3) solve at 1e-11 where the problem has none).

Usage::

    python benchmarks/probe_slab_estimate.py [--stiff]
"""
import sys
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
STIFF = ((problems.mass_spring_chain, {"cubic": 1.0}, ("dG(1)", "dG(2)"), (1e-2,)),
         (problems.mass_spring_chain, {"n": 300}, ("dG(1)", "dG(2)"), (1e-2,)),
         (problems.pollu, {}, ("cG(2)",), (1e-3, 1e-6)))


def row(p, method, tol, compiled, reference=False):
    """The Markdown row of one run of the problem ``p`` (``reference``: where ``p`` has no
    final value, one from a dG(3) solve at 1e-11)."""
    kw = {"method": method, "tolerance": tol, "absolute_tolerance": p.atol_ratio * tol}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = dn.solve(p.ode, **kw)
    warned = any(issubclass(w.category, dn.ToleranceWarning) for w in caught)
    solve, estimate, default = [], [], []
    for _ in range(2):
        start = time.process_time()
        plain = dn.solve(p.ode, estimate_global_error=False, **kw)
        solve.append(time.process_time() - start)
        start = time.process_time()
        global_error.slab_estimate(plain, compiled)
        estimate.append(time.process_time() - start)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", dn.ToleranceWarning)
            start = time.process_time()
            dn.solve(p.ode, **kw)
            default.append(time.process_time() - start)
    final = p.final
    if final is None and reference:
        final = dn.solve(p.ode, method="dG(3)", tolerance=1e-11, absolute_tolerance=1e-11,
                         estimate_global_error=False)(p.T)
    error = float("nan")
    if final is not None:
        error = np.max(np.abs(sol(p.T) - final) / (p.atol_ratio + np.abs(final))) / tol
    found = sol.stats.get("global error estimate", float("nan")) / tol
    kind = "note" if "global error note" in sol.stats else ("W" if warned else "-")
    return (f"| {p.description} | {method} | {tol:.0e} | {error:.3g} | {found:.3g} | {kind} | "
            f"{min(solve):.3f} | {min(estimate) / min(solve):.2f} | "
            f"{min(default) / min(solve):.2f} |")


def main():
    print("| problem | method | tol | error | estimate | warned | solve (s) | cost | default |")
    print("|---|---|---|---|---|---|---|---|---|")
    stiff = "--stiff" in sys.argv
    for make, args, methods, tolerances in STIFF if stiff else RUNS:
        p = make(**args)
        compiled = lower(p.ode)
        for method in methods:
            dn.solve(p.ode, method=method, tolerance=1e-2)  # warm-up: kernels and loops
            for tol in tolerances:
                print(row(p, method, tol, compiled, stiff), flush=True)


if __name__ == "__main__":
    main()
