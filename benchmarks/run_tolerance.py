"""Delivered error against tolerance: how far the error at T lands from the tolerance asked.

For HIRES (T = 321.8122), VDPOL (eps = 1e-6, T = 2) and the harmonic oscillator (T = 100)
of :mod:`dolfinode.bench.problems`, each method solves at tolerances 1e-2..1e-10 with
absolute_tolerance = atol_ratio x tolerance (the problem's ratio), and the delivered error is
the Test Set's scaled error at T, max_i |U_i(T) - u_i(T)| / (atol_ratio + |u_i(T)|), which is
comparable with the tolerance (mescd = -log10 of it). First-order methods stop at 1e-7 (their
step count grows as tol^(-1/2)). Writes tolerance.{json,md} (the default mapping), or with
``--uncalibrated`` (``calibrate_tolerance=False``) tolerance_uncalibrated.{json,md}.

Usage::

    python benchmarks/run_tolerance.py [--output doc/benchmarks] [--methods "cG(2),dG(2)"]
    python benchmarks/run_tolerance.py --uncalibrated
"""
import argparse
import json
import subprocess
from pathlib import Path

import numpy as np

import dolfinode as dn
from dolfinode.bench import problems

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)")
TOLERANCES = tuple(10.0 ** -e for e in range(2, 11))


def cases():
    return [problems.hires_problem(), problems.vdpol(), problems.harmonic_problem()]


def delivered(problem, method, tolerance, calibrate):
    """(scaled error at T, time slabs) of a solve at ``tolerance``; (inf, 0) if it fails."""
    try:
        sol = dn.solve(problem.ode, method=method, tolerance=tolerance,
                       absolute_tolerance=problem.atol_ratio * tolerance,
                       maximum_steps=2_000_000, calibrate_tolerance=calibrate)
    except dn.SolverError:
        return float("inf"), 0
    final = problem.final
    error = np.max(np.abs(sol(problem.T) - final) / (problem.atol_ratio + np.abs(final)))
    return float(error), sol.stats["time slabs"]


def summary(rows):
    """Lines counting the runs within [0.1, 10] x tolerance, the sweeps whose error grows
    more than 1.5x as the tolerance tightens, and the time slabs."""
    within = sum(0.1 <= r["error"] / r["tolerance"] <= 10 for r in rows)
    growing = []
    for key in dict.fromkeys((r["problem"], r["method"]) for r in rows):
        sweep = [r for r in rows if (r["problem"], r["method"]) == key]  # loosest first
        growing += [f"{key[1]} on {key[0]} at {b['tolerance']:.0e}" for a, b in
                    zip(sweep, sweep[1:]) if b["error"] > 1.5 * a["error"]]
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
    calibrate = not args.uncalibrated
    name = "tolerance" if calibrate else "tolerance_uncalibrated"
    methods = args.methods.split(",")
    rows = []
    for problem in cases():
        for method in methods:
            for tolerance in TOLERANCES:
                if method.endswith("(1)") and tolerance < 1e-7:
                    continue
                error, slabs = delivered(problem, method, tolerance, calibrate)
                rows.append({"problem": problem.name, "method": method, "tolerance": tolerance,
                             "error": error, "slabs": slabs})
                print(f"{problem.name:8} {method:6} tol {tolerance:.0e} error {error:.2e} "
                      f"ratio {error / tolerance:8.3g} slabs {slabs}", flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    output = Path(args.output)
    (output / f"{name}.json").write_text(json.dumps({"commit": commit, "runs": rows},
                                                      indent=1) + "\n")
    lines = ["# Delivered error against tolerance"
             + ("" if calibrate else " (calibrate_tolerance=False)"), "",
             "error / tolerance at T (scaled as the Test Set's mescd; `benchmarks/"
             f"run_tolerance.py`, git {commit}); within [0.1, 10] is the target.", "",
             *summary(rows), ""]
    for problem in dict.fromkeys(r["problem"] for r in rows):
        lines += [f"## {problem}", "", "| tolerance | " + " | ".join(methods) + " |",
                  "|---|" + "---|" * len(methods)]
        for tolerance in TOLERANCES:
            cells = []
            for method in methods:
                run = [r for r in rows if r["problem"] == problem and r["method"] == method
                       and r["tolerance"] == tolerance]
                cells.append(f"{run[0]['error'] / tolerance:.2g}" if run else "")
            lines.append(f"| {tolerance:.0e} | " + " | ".join(cells) + " |")
        lines.append("")
    (output / f"{name}.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
