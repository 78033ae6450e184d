"""Cost of events and breakpoints (issue 30's measurements).

1. Overhead of ``events=`` on a long oscillator run: u'' = -u on [0, 1000] (about 320 zero
   crossings of u), cG(2) and mcG(2) at tolerance 1e-8, with and without
   ``events=[u, v - 0.5]``: solve time (median of repeats, compiled kernels cached).
2. The jump cases of the issue (u' = Piecewise((0, t < 0.5), (1, True)); u' = H(t - 0.3);
   u' = u H(t - sqrt(2)/2)) at tolerances 1e-4 and 1e-8: steps, error and time of dolfinode's
   dG(1), cG(2) and mdG(1) (breakpoints found from the declaration) against scipy's
   solve_ivp (RK45, Radau) with the interval split by hand at the jump, the way a scipy user
   handles a known jump today.

Usage::

    .venv/bin/python benchmarks/run_events.py [--output doc/benchmarks]
"""
import argparse
import math
import time
from functools import partial
from pathlib import Path

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

import dolfinode as dn

u, v = sp.symbols("u v")
REPEATS = 7


def median_time(run):
    """Median CPU time of ``run()`` over REPEATS calls (after one warm-up call): the machine
    is shared, and wall times varied by 2x between runs."""
    run()
    times = []
    for _ in range(REPEATS):
        start = time.process_time()
        run()
        times.append(time.process_time() - start)
    return float(np.median(times))


#: The check of the error at T (a reference solve where f jumps or events are given) is
#: left out: these tables time locating events and jumps, as solve_ivp does them.
CHECK = {"estimate_global_error": False}


def overhead():
    ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=1000.0)
    rows = []
    for method in ("cG(2)", "mcG(2)"):
        plain = median_time(partial(dn.solve, ode, method=method, tolerance=1e-8, **CHECK))
        sol = dn.solve(ode, method=method, tolerance=1e-8, events=[u, v - 0.5], **CHECK)
        with_events = median_time(partial(dn.solve, ode, method=method, tolerance=1e-8,
                                          events=[u, v - 0.5], **CHECK))
        rows.append((method, sol.stats["time slabs"], len(sol.t_events[0]), plain,
                     with_events, with_events / plain - 1))
    return rows


JUMPS = {
    "u' = Piecewise((0, t < 0.5), (1, True))": (sp.Piecewise((0, dn.t < 0.5), (1, True)),
                                              lambda t, y: [0.0 if t < 0.5 else 1.0],
                                              0.0, 0.5, 0.5),
    "u' = H(t - 0.3)": (sp.Heaviside(dn.t - 0.3), lambda t, y: [float(t >= 0.3)], 0.0, 0.3,
                        0.7),
    "u' = u H(t - sqrt(2)/2)": (u * sp.Heaviside(dn.t - sp.sqrt(2) / 2),
                                lambda t, y: [y[0] * float(t >= math.sqrt(2) / 2)], 1.0,
                                math.sqrt(2) / 2, math.exp(1 - math.sqrt(2) / 2)),
}


def scipy_split(f, u0, jump, tol, method):
    """solve_ivp on [0, jump] and [jump, 1] (rtol = atol = tol): (steps, u(1))."""
    first = solve_ivp(f, (0.0, jump), [u0], method=method, rtol=tol, atol=tol)
    second = solve_ivp(lambda t, y: f(max(t, jump * (1 + 1e-15)), y), (jump, 1.0),
                       first.y[:, -1], method=method, rtol=tol, atol=tol)
    return len(first.t) + len(second.t) - 2, second.y[0, -1]


def jumps():
    rows = []
    for name, (rhs, f, u0, jump, exact) in JUMPS.items():
        ode = dn.ODE({u: rhs}, u0=[u0], T=1.0)
        for tol in (1e-4, 1e-8):
            for method in ("dG(1)", "cG(2)", "mdG(1)"):
                sol = dn.solve(ode, method=method, tolerance=tol, **CHECK)
                seconds = median_time(partial(dn.solve, ode, method=method, tolerance=tol,
                                              **CHECK))
                rows.append((name, tol, method, sol.stats["time slabs"],
                             abs(sol(1.0)[0] - exact), seconds))
            for method in ("RK45", "Radau"):
                steps, end = scipy_split(f, u0, jump, tol, method)
                seconds = median_time(partial(scipy_split, f, u0, jump, tol, method))
                rows.append((name, tol, f"solve_ivp {method} (split)", steps, abs(end - exact),
                             seconds))
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output", default="doc/benchmarks")
    args = parser.parse_args()
    lines = ["# Events and breakpoints: cost", "",
             ("Made by `benchmarks/run_events.py` (median CPU time of "
              f"{REPEATS} calls, compiled kernels cached; dolfinode with "
              "estimate_global_error=False: the check of the error at T is not timed here)."),
             "",
             "## Overhead of events= on a long oscillator run", "",
             "u'' = -u on [0, 1000], tolerance 1e-8, `events=[u, v - 0.5]` against none.", "",
             "| method | slabs | crossings of u | time without (s) | time with (s) | overhead |",
             "|---|---|---|---|---|---|"]
    for method, slabs, crossings, plain, with_events, ratio in overhead():
        lines.append(f"| {method} | {slabs} | {crossings} | {plain:.4f} | {with_events:.4f} "
                     f"| {100 * ratio:.1f}% |")
    lines += ["", ("## Jumps in f(t): dolfinode (breakpoints from the declaration) against "
                   "solve_ivp split at the jump by hand"), "",
              "| problem | tolerance | method | steps | error at t = 1 | time (s) |",
              "|---|---|---|---|---|---|"]
    for name, tol, method, steps, error, seconds in jumps():
        lines.append(f"| {name} | {tol:g} | {method} | {steps} | {error:.2e} | "
                     f"{seconds:.2e} |")
    Path(args.output).mkdir(parents=True, exist_ok=True)
    out = Path(args.output) / "events.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
