"""Short runs whose error at T grows: Kepler's orbit and a large pendulum against the estimate.

Kepler's orbit (eccentricity 0.5-0.99 over half, one and three periods) and a pendulum of
amplitude 2 and 3 (T = 5, 20), solved by cG(1..3) and dG(1..3) at 1e-2..1e-6 with
``estimate_global_error=True``, against DOP853 at rtol 1e-13: per run the slabs, the error at
T and the estimate (both / tolerance, scaled as the tolerance means it) and the
nonlinearity; then the counts the choice of ``solve.SHORTEST_RUN`` rests on (runs above
10 x the tolerance by slab count, and those the estimate misses or falsely flags).

Usage::

    python benchmarks/probe_short_runs.py
"""
import warnings

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

import dolfinode as dn

METHODS = ("cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)")
TOLERANCES = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)


def kepler_f(t, y):
    r3 = (y[0] ** 2 + y[1] ** 2) ** 1.5
    return [y[2], y[3], -y[0] / r3, -y[1] / r3]


def cases():
    """(name, ode, f, u0, T) of every case."""
    q1, q2, p1, p2 = sp.symbols("q1 q2 p1 p2")
    r3 = (q1**2 + q2**2) ** sp.Rational(3, 2)
    kepler = {q1: p1, q2: p2, p1: -q1 / r3, p2: -q2 / r3}
    for e in (0.5, 0.8, 0.9, 0.95, 0.99):
        for periods in (0.5, 1, 3):
            u0, T = [1 - e, 0.0, 0.0, np.sqrt((1 + e) / (1 - e))], 2 * np.pi * periods
            yield f"Kepler e = {e}, {periods} periods", dn.ODE(kepler, u0, T=T), kepler_f, u0, T
    th, w = sp.symbols("th w")
    for amplitude in (2.0, 3.0):
        for T in (5.0, 20.0):
            yield (f"pendulum {amplitude}, T = {T}",
                   dn.ODE({th: w, w: -sp.sin(th)}, [amplitude, 0.0], T=T),
                   lambda t, y: [y[1], -np.sin(y[0])], [amplitude, 0.0], T)


def main():
    warnings.simplefilter("ignore", dn.ToleranceWarning)
    runs = []
    for name, ode, f, u0, T in cases():
        u = solve_ivp(f, (0.0, T), u0, method="DOP853", rtol=1e-13, atol=1e-14).y[:, -1]
        for method in METHODS:
            for tol in TOLERANCES:
                sol = dn.solve(ode, method, tolerance=tol, estimate_global_error=True)
                error = np.max(np.abs(sol(T) - u) / (tol + tol * np.abs(u)))
                estimate = sol.stats["global error estimate"] / tol
                slabs = sol.stats["time slabs"]
                runs.append((slabs, error, estimate))
                print(f"{name:30s} {method} {tol:.0e} slabs {slabs:6d} error {error:9.3g} "
                      f"estimate {estimate:9.3g} nonlinearity "
                      f"{sol.stats['global error nonlinearity']:.2g}", flush=True)
    above = [r for r in runs if r[1] > 10]
    print(f"\n{len(runs)} runs, {len(above)} above 10 x the tolerance; of those, in fewer than "
          + ", ".join(f"{n} slabs: {sum(r[0] < n for r in above)}" for n in (100, 50, 20, 10)))
    print(f"above 10 x, estimated at most 10 x: {sum(r[2] <= 10 for r in above)}; "
          f"within 10 x, estimated above: {sum(r[1] <= 10 < r[2] for r in runs)}")


if __name__ == "__main__":
    main()
