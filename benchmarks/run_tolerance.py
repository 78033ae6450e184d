"""Delivered error against tolerance: how far the error at T lands from the tolerance asked.

For HIRES (T = 321.8122), VDPOL (eps = 1e-6, T = 2) and the harmonic oscillator (T = 100)
of :mod:`dolfinode.bench.problems`, and for the multi-adaptive methods also two problems whose
components take different steps (the chain of 50 masses with two springs 1e4 x stiffer, T =
10, and the seed model at kappa = 1e2, scored on x1), each method solves at tolerances 1e-2..1e-10 with
absolute_tolerance = atol_ratio x tolerance (the problem's ratio), and the delivered error is
the Test Set's scaled error at T, max_i |U_i(T) - u_i(T)| / (atol_ratio + |u_i(T)|), which is
comparable with the tolerance (mescd = -log10 of it). First-order methods stop at 1e-7 (their
step count grows as tol^(-1/2)). Writes tolerance.{json,md} (the default mapping), or with
``--uncalibrated`` (``calibrate_tolerance=False``) tolerance_uncalibrated.{json,md}; the runs
of the methods given replace theirs in the record, the others' are kept.

Usage::

    python benchmarks/run_tolerance.py [--output doc/benchmarks] [--methods "cG(2),dG(2)"]
    python benchmarks/run_tolerance.py --uncalibrated
    python benchmarks/run_tolerance.py --methods "mcG(1),mcG(2),mcG(3),mdG(1),mdG(2),mdG(3)"
"""
import argparse
import itertools
import json
import subprocess
from pathlib import Path

import numpy as np

import dolfinode as dn
from dolfinode.bench import problems

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)")
TOLERANCES = tuple(10.0 ** -e for e in range(2, 11))


def cases(multi_adaptive):
    """The calibration problems, with the multi-rate ones for multi-adaptive methods."""
    chosen = [problems.hires_problem(), problems.vdpol(), problems.harmonic_problem()]
    if multi_adaptive:
        chosen += [problems.mass_spring_chain(), problems.seed_model(1e2)]
    return chosen


def delivered(problem, method, tolerance, calibrate):
    """(scaled error at T, time slabs, elements) of a solve at ``tolerance``; (inf, 0, 0) if it
    fails."""
    try:
        sol = dn.solve(problem.ode, method=method, tolerance=tolerance,
                       absolute_tolerance=problem.atol_ratio * tolerance,
                       maximum_steps=2_000_000, calibrate_tolerance=calibrate)
    except dn.SolverError:
        return float("inf"), 0, 0
    scored = list(problem.scored or range(problem.ode.N))
    final = problem.final[scored]
    error = np.max(np.abs(sol(problem.T)[scored] - final) / (problem.atol_ratio + np.abs(final)))
    return float(error), sol.stats["time slabs"], sol.stats["elements"]


def summary(rows):
    """Lines counting the runs within [0.1, 10] x tolerance, the sweeps whose error grows
    more than 1.5x as the tolerance tightens, and the time slabs."""
    within = sum(0.1 <= r["error"] / r["tolerance"] <= 10 for r in rows)
    growing = []
    for key in dict.fromkeys((r["problem"], r["method"]) for r in rows):
        sweep = [r for r in rows if (r["problem"], r["method"]) == key]  # loosest first
        growing += [f"{key[1]} on {key[0]} at {b['tolerance']:.0e}" for a, b in
                    itertools.pairwise(sweep) if b["error"] > 1.5 * a["error"]]
    return [f"- runs within [0.1, 10] x tolerance: {within} of {len(rows)}",
            f"- error growing > 1.5x as the tolerance tightens: {len(growing)}"
            + (f" ({', '.join(growing)})" if growing else ""),
            f"- time slabs, all runs: {sum(r['slabs'] for r in rows):,}"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--uncalibrated", action="store_true")
    args = parser.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True, check=False).stdout.strip()
    calibrate = not args.uncalibrated
    name = "tolerance" if calibrate else "tolerance_uncalibrated"
    methods = args.methods.split(",")
    output = Path(args.output)
    record = output / f"{name}.json"
    old = json.loads(record.read_text()) if record.exists() else {"runs": []}
    kept = [{"commit": old.get("commit"), **r} for r in old["runs"] if r["method"] not in methods]
    rows = []
    for problem in cases(any(m.startswith("m") for m in methods)):
        for method in methods:
            if problem.multiscale and not method.startswith("m"):
                continue
            for tolerance in TOLERANCES:
                if method.endswith("(1)") and tolerance < 1e-7:
                    continue
                error, slabs, elements = delivered(problem, method, tolerance, calibrate)
                rows.append({"problem": problem.name, "method": method, "tolerance": tolerance,
                             "error": error, "slabs": slabs, "elements": elements,
                             "commit": commit})
                print(f"{problem.name:8} {method:6} tol {tolerance:.0e} error {error:.2e} "
                      f"ratio {error / tolerance:8.3g} elements {elements}", flush=True)
    rows = kept + rows
    record.write_text(json.dumps({"runs": rows}, indent=1) + "\n")
    methods = list(dict.fromkeys(r["method"] for r in rows))
    multi = [r for r in rows if r["method"].startswith("m")]
    commits = ", ".join(dict.fromkeys(r["commit"] for r in rows))
    lines = ["# Delivered error against tolerance"
             + ("" if calibrate else " (calibrate_tolerance=False)"), "",
             ("error / tolerance at T (scaled as the Test Set's mescd; `benchmarks/"
             f"run_tolerance.py`, git {commits}); within [0.1, 10] is the target."), "",
             "Mono-adaptive methods:", *summary([r for r in rows if r not in multi]), ""]
    if multi:
        lines += ["Multi-adaptive methods:", *summary(multi), ""]
    for problem in dict.fromkeys(r["problem"] for r in rows):
        shown = [m for m in methods if any(r["problem"] == problem and r["method"] == m
                                           for r in rows)]
        lines += [f"## {problem}", "", "| tolerance | " + " | ".join(shown) + " |",
                  "|---|" + "---|" * len(shown)]
        for tolerance in TOLERANCES:
            cells = []
            for method in shown:
                run = [r for r in rows if r["problem"] == problem and r["method"] == method
                       and r["tolerance"] == tolerance]
                cells.append(f"{run[0]['error'] / tolerance:.2g}" if run else "")
            lines.append(f"| {tolerance:.0e} | " + " | ".join(cells) + " |")
        lines.append("")
    (output / f"{name}.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
