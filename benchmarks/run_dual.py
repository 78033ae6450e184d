"""Error estimates from the dual problem: effectivity indices, and goal-oriented versus plain
adaptivity at equal error in the goal.

    PYTHONPATH=. python benchmarks/run_dual.py [--quick]

Writes doc/benchmarks/dual.{md,csv,json}. The scaling table times ``estimate_error`` against the
number of components N and sets it beside the dense per-interval solve of commit 067e65f
(doc/benchmarks/dual_scaling_dense.json, measured with this script's ``scaling`` at that commit). Effectivity = est.value / (M(U) - M(u)) for the goal
M(u) = u_1(T); references are exact (matrix exponential) or scipy DOP853 at rtol 1e-13.
Goal-oriented runs ``solve(..., goal=..., tolerance=TOL)`` are compared with plain runs whose
tolerance is lowered by factors of 2 from 1000 TOL until their true goal error is at most the
goal-oriented run's; work is the total number of elements and the wall time of every primal and dual solve.
"""
import argparse
import csv
import json
import pathlib
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

import dolfinode as dn
from dolfinode.compile import lower
from dolfinode.problems import (
    driven_oscillator,
    estimate_suite,
    mass_spring_chain,
    reaction_diffusion_front,
)

OUT = pathlib.Path(__file__).resolve().parents[1] / "doc" / "benchmarks"
METHODS = ["cG(1)", "cG(2)", "dG(1)", "dG(2)", "mcG(1)", "mcG(2)", "mdG(1)", "mdG(2)"]


def effectivity(problems, quick):
    rows = []
    for name, (ode, reference) in problems.items():
        for method in METHODS:
            low = method.endswith("G(1)") and "dG" not in method
            tolerances = [1e-4, 1e-5] if low else [1e-4, 1e-6]
            if quick:
                tolerances = tolerances[:1]
            for tolerance in tolerances:
                sol = dn.solve(ode, method=method, tolerance=tolerance)
                start = time.perf_counter()
                est = dn.estimate_error(sol, {ode.states[0]: 1.0})
                elapsed = time.perf_counter() - start
                error = sol(ode.T)[0] - reference[0]
                rows.append({"problem": name, "method": method, "tolerance": tolerance,
                             "elements": int(sol.stats["elements"]), "error": error,
                             "estimate": est.value, "effectivity": est.value / error,
                             "bound/error": est.bound / abs(error),
                             "S0": est.stability_factors["S0"],
                             "S1": est.stability_factors["S1"],
                             "estimate time [s]": elapsed,
                             "solve time [s]": sol.stats["solve time"]})
                print(f"{name:12s} {method:7s} {tolerance:.0e} eff {rows[-1]['effectivity']:.3f}"
                      f" bound/err {rows[-1]['bound/error']:.2f}", flush=True)
    return rows


def goal_versus_plain(problems, quick):
    ode, exact = driven_oscillator()
    runs = [("driven oscillator", ode, np.atleast_1d(exact(ode.T)), m, tol)
            for m in ("mcG(2)", "mdG(1)", "cG(2)") for tol in (1e-5, 1e-7)]
    runs += [(name, *problems[name], m, tol) for name, m, tol in
             [("random 10", "mcG(2)", 1e-6), ("lorenz", "cG(2)", 1e-5),
              ("van der pol", "mdG(2)", 1e-6)]]
    if quick:
        runs = runs[:2]
    rows = []
    for name, ode, reference, method, tolerance in runs:
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            sol = dn.solve(ode, method=method, goal={ode.states[0]: 1.0}, tolerance=tolerance)
        goal_time = time.perf_counter() - start
        goal_error = abs(sol(ode.T)[0] - reference[0])
        history = sol.stats["goal history"]
        plain_tol = 1e3 * tolerance
        while True:  # the loosest plain tolerance (by factors of 2) reaching the same error
            start = time.perf_counter()
            plain = dn.solve(ode, method=method, tolerance=plain_tol)
            plain_time = time.perf_counter() - start
            plain_error = abs(plain(ode.T)[0] - reference[0])
            if plain_error <= goal_error or plain_tol < 1e-13:
                break
            plain_tol /= 2
        rows.append({"problem": name, "method": method, "goal tolerance": tolerance,
                     "goal error": goal_error, "goal iterations": len(history),
                     "goal elements (final)": int(sol.stats["elements"]),
                     "goal elements (all iterations)": sum(h["elements"] for h in history),
                     "goal time [s]": goal_time, "plain tolerance": plain_tol,
                     "plain error": plain_error, "plain elements": int(plain.stats["elements"]),
                     "plain time [s]": plain_time})
        print(rows[-1], flush=True)
    return rows


def _middle_mass(N):
    """The chain of N // 2 masses, and its goal: the middle mass's position at T."""
    ode = mass_spring_chain(N // 2)[0]
    goal = np.zeros(ode.N)
    goal[ode.N // 4] = 1.0
    return ode, goal


def _front_mean(N):
    """The Fisher front on N points, and its goal: the mean of u at T (the front position)."""
    ode = reaction_diffusion_front(N)
    return ode, np.full(ode.N, 1.0 / ode.N)


#: (name, (ode, goal) by N, method, tolerance) of the scaling runs.
SCALING = [("mass-spring chain", _middle_mass, "cG(2)", 1e-6),
           ("mass-spring chain", _middle_mass, "mcG(2)", 1e-6),
           ("reaction-diffusion front", _front_mean, "cG(2)", 1e-5)]


def scaling(sizes, limit):
    """Time of ``estimate_error`` (and of the primal solve) against the number of components
    N; a problem stops growing once one estimate takes longer than ``limit`` seconds."""
    rows = []
    for name, make, method, tolerance in SCALING:
        ode, goal = make(10)
        dn.estimate_error(dn.solve(ode, method=method, tolerance=tolerance), goal)  # compile
        for N in sizes:
            ode, goal = make(N)
            sol = dn.solve(ode, method=method, tolerance=tolerance)
            start = time.perf_counter()
            est = dn.estimate_error(sol, goal)
            elapsed = time.perf_counter() - start
            rows.append({"problem": name, "method": method, "tolerance": tolerance,
                         "N": ode.N, "bandwidth": sum(lower(ode).ordering[2:]),
                         "elements": int(sol.stats["elements"]),
                         "union intervals": len(est.dual.grid) - 1,
                         "solve time [s]": sol.stats["solve time"],
                         "estimate time [s]": elapsed, "estimate": est.value})
            print(rows[-1], flush=True)
            if elapsed > limit:
                break
    return rows


def _table(rows, formats):
    keys = list(rows[0])
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for row in rows:
        lines.append("| " + " | ".join(formats.get(k, "{}").format(row[k]) for k in keys) + " |")
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a few cases only")
    args = parser.parse_args()
    problems = estimate_suite()
    effect = effectivity(problems, args.quick)
    versus = goal_versus_plain(problems, args.quick)
    sizes = scaling([10, 100] if args.quick else [10, 100, 1000, 4000], limit=60.0)
    dense = json.loads((OUT / "dual_scaling_dense.json").read_text())["rows"]
    dense = {(r["problem"], r["method"], r["N"]): r["estimate time [s]"] for r in dense}
    for row in sizes:
        key = (row["problem"], row["method"], row["N"])
        row["dense estimate time [s]"] = dense.get(key, float("nan"))
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "dual.json").write_text(json.dumps({"effectivity": effect, "goal_vs_plain": versus,
                                               "scaling": sizes}, indent=1, default=float))
    with open(OUT / "dual.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(effect[0]))
        writer.writeheader()
        writer.writerows(effect)
    effs = np.array([r["effectivity"] for r in effect])
    bounds = np.array([r["bound/error"] for r in effect])
    g = "{:.3g}"
    text = [
        "# Dual-based error estimates", "",
        (f"Measured {time.strftime('%Y-%m-%d')} with `benchmarks/run_dual.py` on the machine of "
        "this run (2 cores, shared). Goal: M(u) = u_1(T)."), "",
        (f"**Effectivity** est.value / true error over {len(effect)} runs: min {effs.min():.3f}, "
        f"median {np.median(effs):.3f}, max {effs.max():.3f}; bound / |error| >= "
        f"{bounds.min():.3f} (never below 1 means the bound held)."), "",
        _table(effect, {"tolerance": "{:.0e}", "error": "{:.2e}", "estimate": "{:.2e}",
                        "effectivity": "{:.3f}", "bound/error": "{:.2f}", "S0": g, "S1": g,
                        "estimate time [s]": "{:.3f}", "solve time [s]": "{:.3f}"}),
        "", "## Goal-oriented versus plain adaptivity at equal goal error", "",
        ("Plain: the loosest tolerance (halving from 1000 x the goal tolerance) whose goal error "
        "is at most the goal-oriented run's; its time is that one solve (the search for the "
        "tolerance, which a user would have to do by hand, is not counted). Goal time includes "
        "every primal and dual solve of the loop."), "",
        _table(versus, {"goal tolerance": "{:.0e}", "goal error": "{:.2e}",
                        "goal time [s]": "{:.3f}", "plain tolerance": "{:.2e}",
                        "plain error": "{:.2e}", "plain time [s]": "{:.3f}"}),
        "", "## Cost against the number of components", "",
        ("`estimate_error` (both duals, of degree r = q + 2 and r - 1, and the error "
         "representation) for a goal at T: the middle mass's position of a chain of N/2 masses "
         "(`problems.mass_spring_chain`), the mean of a Fisher front on N points "
         "(`problems.reaction_diffusion_front`). Bandwidth: kl + ku of the Jacobian in its "
         "bandwidth ordering. Dense: the same runs with the dense per-interval solve of commit "
         "067e65f (nan: not run, it exceeded 30 s at a smaller N). The first call, which compiles "
         "the loops, is not timed; neither is the kernels' code generation."), "",
        _table(sizes, {"tolerance": "{:.0e}", "solve time [s]": "{:.3f}",
                       "estimate time [s]": "{:.3f}", "estimate": "{:.3e}",
                       "dense estimate time [s]": "{:.2f}"}),
    ]
    (OUT / "dual.md").write_text("\n".join(text) + "\n")
    print("wrote", OUT / "dual.md")


if __name__ == "__main__":
    main()
