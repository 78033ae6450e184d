"""Where the error at T of a run is made: each slab's share, replayed against Radau.

A default solve of a problem of :mod:`dolfinode.bench.problems` is cut at the times where every
component has an element end (the slab ends of a multi-adaptive run, every step of a
mono-adaptive one). From each such U(t_{n-1}), scipy's Radau (rtol 1e-12) gives the exact flow
to t_n (the slab's end error U(t_n) - u(t_n; t_{n-1}, U(t_{n-1}))) and to T; the slab's share of
the error at T is the change of the flow to T between its two ends, so the shares add up to
the error at T. Prints the slabs with the largest shares, scaled as run_tolerance.py scores
(atol_ratio + |u(T)|) and in units of the tolerance (doc/design/tolerance.md, "One slab long
against its time scale").

Usage::

    python benchmarks/replay_tolerance.py HIRES "mdG(3)" 1e-7 [--shown 8]
"""
import argparse

import numpy as np
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode.bench import problems
from dolfinode.bench.numpy_functions import numpy_functions

PROBLEMS = {"HIRES": problems.hires_problem, "VDPOL": problems.vdpol,
            "harmonic": problems.harmonic_problem, "ROBER": problems.rober,
            "POLLU": problems.pollu}


def slab_ends(sol, u0):
    """(times, values): t0 and the times where every component has an element end, with the
    end values there (dG's left limits)."""
    ptr, _, t_end, values = sol.elements()
    ends = [dict(zip(t_end[ptr[i]:ptr[i + 1]], values[ptr[i]:ptr[i + 1], -1]))
            for i in range(len(ptr) - 1)]
    times = sorted(set.intersection(*(set(e) for e in ends)))
    return [0.0] + times, [np.asarray(u0, float)] + [np.array([e[t] for e in ends])
                                                     for t in times]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("problem", choices=sorted(PROBLEMS))
    parser.add_argument("method")
    parser.add_argument("tolerance", type=float)
    parser.add_argument("--shown", type=int, default=8)
    args = parser.parse_args()
    problem, tol = PROBLEMS[args.problem](), args.tolerance
    ode = problem.ode
    sol = dn.solve(ode, method=args.method, tolerance=tol,
                   absolute_tolerance=problem.atol_ratio * tol)
    fun, jac = numpy_functions(ode)

    def flow(t0, y0, t1):
        if t1 <= t0:
            return y0
        return solve_ivp(fun, (t0, t1), y0, method="Radau", jac=jac, rtol=1e-12,
                         atol=1e-14 * problem.atol_ratio).y[:, -1]

    times, U = slab_ends(sol, ode.u0)
    weight = 1.0 / ((problem.atol_ratio + np.abs(problem.final)) * tol)
    total = (U[-1] - problem.final) * weight
    worst = int(np.argmax(np.abs(total)))
    print(f"{args.problem} {args.method} at {tol:g}: error at T {abs(total[worst]):.3g} x the "
          f"tolerance in {ode.states[worst]}, {len(times) - 1} slabs, "
          f"{sol.stats['elements']} elements")
    shares, before = [], flow(times[0], U[0], problem.T)
    for n in range(1, len(times)):
        after = flow(times[n], U[n], problem.T)
        end_error = (U[n] - flow(times[n - 1], U[n - 1], times[n])) * weight
        shares.append((n, (after - before) * weight, end_error))
        before = after
    for n, share, end_error in sorted(shares, key=lambda s: -abs(s[1][worst]))[:args.shown]:
        i = int(np.argmax(np.abs(end_error)))
        print(f"  slab {n} [{times[n - 1]:.4g}, {times[n]:.4g}]: share {share[worst]:+.3g}; "
              f"end error {end_error[i]:+.3g} in {ode.states[i]}")


if __name__ == "__main__":
    main()
