"""Multi-adaptive runs at loose tolerances: the true error at T and mid-run, the estimate, the
warnings.

Each problem class (a stiff component u' = -r (u - cos t) read by a slow v' = u - v/10 for
r = 1e2..1e5, a stiff linear 2 x 2 with a slow mode, HIRES, Van der Pol at mu = 10, a 20-mass
chain, the reaction front on 50 points, a driven stiff oscillator) is solved by mcG(1..3) and
mdG(0..2) at tolerances 1e-1, 3e-2, 1e-2, 3e-3 (absolute_tolerance = ratio x tolerance, the
problem's ratio) and compared with scipy's Radau at rtol 1e-12: the error at T, at every
element end of every component (each component at all ends) and on a grid of 4001 times, in
units of the tolerance as :func:`dolfinode.global_error.scaled` measures it (|e_i| / (ratio +
|u_i(t)|)); with sol.stats' "global error estimate" and "global error mid-run" and the
ToleranceWarnings raised. A run is *silent* when its largest error exceeds 10 x and it raised
none, a *false alarm* when it warned within 10 x. Prints one JSON line per run, then with
``--table BEFORE.jsonl`` the markdown rows of both records side by side.

Usage::

    python benchmarks/run_multiadaptive_loose.py > after.jsonl
    python benchmarks/run_multiadaptive_loose.py --table before.jsonl after.jsonl
"""
import argparse
import json
import time
import warnings

import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode import problems
from dolfinode.bench import problems as bench
from dolfinode.compile import lower
from dolfinode.global_error import _evaluators

METHODS = ("mcG(1)", "mcG(2)", "mcG(3)", "mdG(0)", "mdG(1)", "mdG(2)")
TOLERANCES = (1e-1, 3e-2, 1e-2, 3e-3)


def follow(rate):
    """u' = -rate (u - cos t), stiff on steps beyond 1 / rate, read by a slow v."""
    u, v = sp.symbols("u v")
    return dn.ODE({u: -rate * (u - sp.cos(dn.t)), v: u - 0.1 * v}, u0={u: 0.0, v: 1.0}, T=10.0)


def cases():
    """(name, ode, absolute tolerance ratio) of the classes swept."""
    y1, y2 = sp.symbols("y1 y2")
    out = [(f"follow {r:.0e}", follow(r), 1.0) for r in (1e2, 1e3, 1e4, 1e5)]
    out += [("linear 2x2", dn.ODE({y1: -1000 * y1 + 999 * y2, y2: -y2}, u0=[2.0, 1.0], T=5.0),
             1.0),
            ("HIRES", bench.hires_problem().ode, 1e-4),
            ("VDPOL mu=10", problems.van_der_pol(T=10.0, mu=10.0), 1.0),
            ("spring chain 20", problems.mass_spring_chain(20, T=10.0)[0], 1.0),
            ("reaction front 50", bench.reaction_front(n=50, T=0.05).ode, 1.0),
            ("driven oscillator", problems.driven_oscillator()[0], 1.0)]
    return out


def reference(ode):
    """scipy's Radau at rtol 1e-12, atol 1e-14 with dense output, on the compiled f and J."""
    compiled = lower(ode)
    jacobian = _evaluators(compiled)[1]
    return solve_ivp(lambda t, u: compiled.f(np.ascontiguousarray(u), t), (ode.t0, ode.T),
                     np.array(ode.u0, dtype=float), method="Radau", rtol=1e-12, atol=1e-14,
                     dense_output=True,
                     jac=lambda t, u: jacobian(np.array([t]), np.ascontiguousarray(u)[None])[0])


def run(name, ode, ratio, exact, method, tol):
    """The record of one run (see the module docstring)."""
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = dn.solve(ode, method=method, tolerance=tol, absolute_tolerance=ratio * tol)
    seconds = time.perf_counter() - start
    told = [str(w.message) for w in caught if issubclass(w.category, dn.ToleranceWarning)]
    ends = np.unique(np.concatenate([np.add(*sol.time_steps(i)) for i in range(ode.N)]))

    def error(times):
        V = exact.sol(times)
        return float(np.max(np.abs(sol(times) - V) / (ratio + np.abs(V)), initial=0.0)) / tol

    return {"problem": name, "method": method, "tol": tol, "T": error(np.array([ode.T])),
            "ends": error(ends[ends < ode.T]), "dense": error(np.linspace(ode.t0, ode.T, 4001)),
            "est": sol.stats.get("global error estimate", np.nan) / tol,
            "est_mid": sol.stats.get("global error mid-run", np.nan) / tol,
            "elements": int(sol.stats["elements"]), "time": seconds, "warned": told}


def verdict(r):
    """SILENT (above 10 x, no warning), FALSE (a warning within 10 x), W (warned of the
    error at T), M (of an error mid-run alone) or - (within 10 x, none)."""
    mid = ("the estimated error mid-run", "the measured error mid-run")
    kind = "-" if not r["warned"] else ("M" if all(w.startswith(mid) for w in r["warned"])
                                        else "W")
    worst = max(r["T"], r["ends"], r["dense"])
    if worst > 10 and kind == "-":
        return "SILENT"
    return "FALSE" if worst <= 10 and kind != "-" else kind


def table(before, after):
    """Markdown rows: T / ends / grid / estimate at T / estimate mid-run / elements and the
    verdict, of each run in ``before`` and ``after`` (JSON-lines files)."""
    def load(path):
        return {(r["problem"], r["method"], r["tol"]): r
                for r in map(json.loads, open(path, encoding="utf-8"))}

    def cell(r):
        return (f"{r['T']:.2g} / {r['ends']:.2g} / {r['dense']:.2g} / {r['est']:.2g} / "
                f"{r['est_mid']:.2g} / {r['elements']} {verdict(r)}")

    old, new = load(before), load(after)
    rows = ["| problem | method | tol | before | after |", "|---|---|---|---|---|"]
    rows += [f"| {k[0]} | {k[1]} | {k[2]:g} | {cell(old[k])} | {cell(new[k])} |" for k in old]
    for label, record in (("before", old), ("after", new)):
        counts = {v: sum(verdict(r) == v for r in record.values())
                  for v in ("SILENT", "FALSE", "W", "M")}
        above = sum(max(r["T"], r["ends"], r["dense"]) > 10 for r in record.values())
        rows.append(f"\n{label}: {len(record)} runs, {above} above 10 x, {counts}")
    return "\n".join(rows)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--table", nargs=2, metavar=("BEFORE", "AFTER"))
    args = parser.parse_args()
    if args.table:
        print(table(*args.table))
        return
    for name, ode, ratio in cases():
        exact = reference(ode)
        for method in METHODS:
            for tol in TOLERANCES:
                print(json.dumps(run(name, ode, ratio, exact, method, tol)), flush=True)


if __name__ == "__main__":
    main()
