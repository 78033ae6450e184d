"""Per-call cost: a trivial solve (y' = -y, y(0) = 1 on [0, 1e-6]) called in a loop.

Each variant is called ``--number`` times per repeat after an untimed warm-up (compile
excluded); the repeats of all variants are interleaved, in a new random order each time,
and the minimum time per call over the repeats is reported (wall clock, ``time.perf_counter``: a call is microseconds, and the
minimum is the least disturbed by the other processes of a shared machine). Variants:
``dn.solve`` per method; ``dn.Solver(...).solve()``, with other u0 and parameter values,
and with a new parameter value at every call (a fit); the compiled start and loop of a
prepared call alone, with its kept arguments (from the state the last call left);
numbalsoda's LSODA (its C code, a numba cfunc right-hand side) with its arrays ready, when
numbalsoda is installed (``pip install numbalsoda``).

Writes per_call.json and per_call.md to the output folder.

Usage::

    python benchmarks/run_per_call.py [--output doc/benchmarks] [--repeats 60] [--number 50]
"""
import argparse
import itertools
import json
import platform
import random
import subprocess
import time
from pathlib import Path

import numpy as np
import sympy as sp

import dolfinode as dn

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("cG(1)", "cG(2)", "dG(0)", "dG(2)", "mcG(1)")


def variants():
    """name -> a function making one call."""
    y, a = sp.symbols("y a")
    ode = dn.ODE({y: -a * y}, u0=[1.0], T=1e-6, params={a: 1.0})
    calls = {f"dn.solve, {m}": (lambda m=m: dn.solve(ode, method=m)) for m in METHODS}
    for m in ("cG(2)", "dG(2)", "mcG(1)"):
        solver = dn.Solver(ode, method=m)
        calls[f"Solver.solve(), {m}"] = solver.solve
        calls[f"Solver.solve(u0=, params=), {m}"] = (
            lambda solver=solver: solver.solve(u0=[2.0], params={a: 1.5}))
    # the floor of a prepared call: its compiled start and loop alone, arguments kept
    prepared = dn.Solver(ode, method="dG(2)")
    prepared.solve()
    (advance, arguments), (started_at, started) = prepared._loop, prepared._start
    calls["compiled start + loop of Solver.solve(), dG(2)"] = lambda: (
        started_at(*started), advance(*arguments))
    # a fit: a new parameter value at every call
    fit, values = dn.Solver(ode, method="dG(2)"), itertools.count()
    calls["Solver.solve(params= new value), dG(2)"] = (
        lambda: fit.solve(params={a: 1.0 + 1e-9 * next(values)}))
    try:
        from numba import cfunc
        from numbalsoda import lsoda, lsoda_sig
    except ImportError:
        return calls

    @cfunc(lsoda_sig)
    def rhs(t, u, du, p):
        du[0] = -p[0] * u[0]

    address, u0, times, data = rhs.address, np.array([1.0]), np.array([0.0, 1e-6]), np.ones(1)
    # all arguments positional: numba types omitted defaults on every call (118 against 6 us)
    calls["numbalsoda lsoda"] = lambda: lsoda(address, u0, times, data, 1e-3, 1e-6, 10000)
    return calls


def measure(calls, repeats, number):
    """Minimum seconds per call of each variant over interleaved repeats."""
    for call in calls.values():
        call()
    best = dict.fromkeys(calls, np.inf)
    order = list(calls)
    shuffle = random.Random(0).shuffle
    for _ in range(repeats):
        # in a new order each repeat: in a fixed one, the first batch (after numbalsoda's)
        # ran 3-5 us a call slower, whichever variant it was
        shuffle(order)
        for name in order:
            call = calls[name]
            start = time.perf_counter()
            for _ in range(number):
                call()
            best[name] = min(best[name], (time.perf_counter() - start) / number)
    return best


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    parser.add_argument("--repeats", type=int, default=60)
    parser.add_argument("--number", type=int, default=50)
    args = parser.parse_args()
    best = measure(variants(), args.repeats, args.number)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True, check=False).stdout.strip()
    record = {"commit": commit, "machine": platform.processor() or platform.machine(),
              "microseconds": {name: 1e6 * seconds for name, seconds in best.items()}}
    output = Path(args.output)
    (output / "per_call.json").write_text(json.dumps(record, indent=1) + "\n")
    reference = best.get("numbalsoda lsoda")
    lines = ["# Per-call cost", "",
             ("A trivial solve, y' = -a y on [0, 1e-6], called in a loop: the minimum over "
             f"{args.repeats} interleaved repeats of {args.number} calls "
             f"(`benchmarks/run_per_call.py`, git {commit})."), "",
             "| call | us per call |" + (" ratio to numbalsoda |" if reference else ""),
             "|---|---|" + ("---|" if reference else "")]
    for name, seconds in best.items():
        ratio = f" {seconds / reference:.1f} |" if reference else ""
        lines.append(f"| {name} | {1e6 * seconds:.1f} |{ratio}")
    (output / "per_call.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
