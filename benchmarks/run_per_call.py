"""Per-call cost: a trivial solve (y' = -y, y(0) = 1 on [0, 1e-6]) called in a loop.

Each variant is called ``--number`` times per repeat after an untimed warm-up (compile
excluded); the repeats of all variants are interleaved, in a new random order each time,
and the minimum time per call over the repeats is reported (wall clock, ``time.perf_counter``: a
call is microseconds, and the minimum is the least disturbed by the other processes of a shared
machine). Variants: ``dn.solve`` per method; ``dn.Solver(...).solve()``, with other u0 and parameter
values, and with a new parameter value at every call (a fit); the compiled start and loop of a
prepared call alone (their one compiled call, :mod:`dolfinode.timeslab.prepared`), with its
kept work space (from the state the last call left);
numbalsoda's LSODA (its C code, a numba cfunc right-hand side) with its arrays ready, when
numbalsoda is installed (``pip install numbalsoda``).

Writes per_call.json to the output folder and the "Latest" section of its per_call.md; the
section it replaces and the dated ones after it, the record's history, are kept.

Usage::

    python benchmarks/run_per_call.py [--output doc/benchmarks] [--repeats 60] [--number 50]
"""
import argparse
import itertools
import json
import os
import platform
import random
import subprocess
import time
from datetime import date
from pathlib import Path

import numpy as np
import sympy as sp

import dolfinode as dn

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("cG(1)", "cG(2)", "dG(0)", "dG(2)", "mcG(1)")
#: The small stiff problems of the peers benchmark whose calls are taken apart.
STIFF = ("HIRES", "ROBER", "POLLU", "VDPOL")


def variants():
    """name -> a function making one call."""
    y, a = sp.symbols("y a")
    ode = dn.ODE({y: -a * y}, u0=[1.0], T=1e-6, params={a: 1.0})
    calls = {f"dn.solve, {m}": (lambda m=m: dn.solve(ode, method=m)) for m in METHODS}
    calls["dn.solve, dG(2), options new to the declaration"] = lambda: (
        ode.__dict__.pop("_kept_solvers", None), dn.solve(ode, method="dG(2)"))
    for m in ("cG(2)", "dG(2)", "mcG(1)"):
        solver = dn.Solver(ode, method=m)
        calls[f"Solver.solve(), {m}"] = solver.solve
        calls[f"Solver.solve(u0=, params=), {m}"] = (
            lambda solver=solver: solver.solve(u0=[2.0], params={a: 1.5}))
    # the floor of a prepared call: its compiled start and loop alone (one call), arguments kept
    prepared = dn.Solver(ode, method="dG(2)")
    prepared.solve()
    run, workspace = prepared._prepared
    calls["compiled start + loop of Solver.solve(), dG(2)"] = lambda: run(workspace)
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


def stiff_variants():
    """(problem, name) -> a function making one call, on the small stiff problems of the
    peers benchmark (dG(3), tolerance 1e-6, their absolute tolerance): dn.solve the first
    time with its options (the general path; the kept solvers dropped before each call) and
    again (a kept solver, :mod:`dolfinode.kept`), with the evaluation at the 100 points the
    benchmark times, dn.Solver.solve(), the compiled start and loop alone, the evaluation
    alone."""
    from dolfinode.bench.problems import get_problem
    from dolfinode.bench.runner import Case

    calls = {}
    for name in STIFF:
        case = Case(get_problem(name))
        ode, times = case.ode, case.t_eval
        options = {"tolerance": 1e-6, "absolute_tolerance": 1e-6 * case.problem.atol_ratio}
        sol = dn.solve(ode, "dG(3)", **options)
        solver = dn.Solver(ode, "dG(3)", **options)
        solver.solve()
        run, workspace = solver._prepared
        x = solver._kept[3]
        calls.update({
            (name, "dn.solve, options new to the declaration"): lambda ode=ode, options=options: (
                ode.__dict__.pop("_kept_solvers", None), dn.solve(ode, "dG(3)", **options)),
            (name, "dn.solve, options seen before"): (
                lambda ode=ode, options=options: dn.solve(ode, "dG(3)", **options)),
            (name, "dn.solve + sol(t_eval), options seen before"): (
                lambda ode=ode, options=options, times=times: dn.solve(ode, "dG(3)",
                                                                       **options)(times)),
            (name, "Solver.solve()"): solver.solve,
            (name, "compiled start + loop"): lambda ode=ode, x=x, run=run, workspace=workspace: (
                x.__setitem__(slice(None), ode.u0), run(workspace)),
            (name, "sol(t_eval)"): lambda sol=sol, times=times: sol(times)})
    return calls


def measure(calls, repeats, number, clock=time.perf_counter):
    """Minimum seconds per call of each variant over interleaved repeats (``clock``)."""
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
            start = clock()
            for _ in range(number):
                call()
            best[name] = min(best[name], (clock() - start) / number)
    return best


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    parser.add_argument("--repeats", type=int, default=60)
    parser.add_argument("--number", type=int, default=50)
    parser.add_argument("--stiff-repeats", type=int, default=30,
                        help="repeats of 10 calls on each small stiff problem")
    args = parser.parse_args()
    best = measure(variants(), args.repeats, args.number)
    # CPU time: a batch of these calls lasts milliseconds, longer than a time slice of a
    # shared machine, and the wall-clock minimum over tens of repeats still held preemptions
    stiff = measure(stiff_variants(), args.stiff_repeats, 10, time.process_time)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True, check=False).stdout.strip()
    record = {"commit": commit, "machine": platform.processor() or platform.machine(),
              "microseconds": {name: 1e6 * seconds for name, seconds in best.items()},
              "stiff microseconds": {problem: {name: 1e6 * seconds
                                               for (p, name), seconds in stiff.items()
                                               if p == problem} for problem in STIFF}}
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    (output / "per_call.json").write_text(json.dumps(record, indent=1) + "\n")
    reference = best.get("numbalsoda lsoda")
    load = ", ".join(f"{value:.1f}" for value in os.getloadavg())
    lines = [f"## Latest (git {commit}, {date.today()}; load average {load})", "",
             ("A trivial solve, y' = -a y on [0, 1e-6], called in a loop: the minimum over "
              f"{args.repeats} interleaved repeats of {args.number} calls."), "",
             "| call | us per call |" + (" ratio to numbalsoda |" if reference else ""),
             "|---|---|" + ("---|" if reference else "")]
    for name, seconds in best.items():
        ratio = f" {seconds / reference:.1f} |" if reference else ""
        lines.append(f"| {name} | {1e6 * seconds:.1f} |{ratio}")
    lines += ["", ("dG(3) at tolerance 1e-6 on the small stiff problems of the peers benchmark: "
                   f"the minimum CPU time (`time.process_time`) over {args.stiff_repeats} "
                   "interleaved repeats of 10 calls; "
                   "the Python of a call is its time less the compiled start and loop's."), "",
              "| call | " + " | ".join(STIFF) + " |", "|---|" + "---|" * len(STIFF)]
    names = list(dict.fromkeys(name for _, name in stiff))
    for name in names:
        lines.append(f"| {name} | " + " | ".join(f"{1e6 * stiff[p, name]:.1f}" for p in STIFF)
                     + " |")
    for name in names[:2] + names[3:4]:
        lines.append(f"| Python of {name} | " + " | ".join(
            f"{1e6 * (stiff[p, name] - stiff[p, 'compiled start + loop']):.1f}" for p in STIFF)
            + " |")
    write_latest(output / "per_call.md", lines)
    print("\n".join(lines))


def write_latest(path, lines):
    """Make ``lines`` the "## Latest" section of ``path``: the text before it is kept, and the
    section it replaces becomes the first dated one after it ("## Earlier (git ...)")."""
    text = path.read_text() if path.exists() else "# Per-call cost\n\n"
    head, found, previous = text.partition("## Latest")
    previous = "## Earlier" + previous if found else ""
    path.write_text(head + "\n".join(lines) + "\n" + ("\n" + previous if previous else ""))

if __name__ == "__main__":
    main()
