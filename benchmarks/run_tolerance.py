"""Delivered error against tolerance: how far the error at T lands from the tolerance asked.

For HIRES (T = 321.8122), VDPOL (eps = 1e-6, T = 2) and the harmonic oscillator (T = 100)
of :mod:`dolfinode.bench.problems`, and for the multi-adaptive methods also two problems whose
components take different steps (the chain of 50 masses with two springs 1e4 x stiffer, T =
10, and the seed model at kappa = 1e2, scored on x1), each method solves at tolerances 1e-2..1e-10
with absolute_tolerance = atol_ratio x tolerance (the problem's ratio), and the delivered error is
the Test Set's scaled error at T, max_i |U_i(T) - u_i(T)| / (atol_ratio + |u_i(T)|), which is
comparable with the tolerance (mescd = -log10 of it). First-order methods stop at 1e-7 (their
step count grows as tol^(-1/2)). Writes tolerance.{json,md} (the default mapping), or with
``--uncalibrated`` (``calibrate_tolerance=False``) tolerance_uncalibrated.{json,md}; the runs
of the problems and methods given replace theirs in the record, the others' are kept.

``--problems out-of-sample`` runs the problems the mapping was not fitted on instead (ROBER,
POLLU, VDPOLM and a stiff linear system, the heat equation of :func:`heat_problem`), with
cG(2), cG(3), dG(1), dG(2), dG(3) at 1e-3..1e-9 unless ``--methods`` says otherwise; each run
records whether it raised a :class:`dolfinode.ToleranceWarning` (marked W in the tables).

Usage::

    python benchmarks/run_tolerance.py [--output doc/benchmarks] [--methods "cG(2),dG(2)"]
    python benchmarks/run_tolerance.py --uncalibrated
    python benchmarks/run_tolerance.py --methods "mcG(1),mcG(2),mcG(3),mdG(1),mdG(2),mdG(3)"
    python benchmarks/run_tolerance.py --problems out-of-sample
    python benchmarks/run_tolerance.py --global-error [--problems out-of-sample]

Runs use the default ``estimate_global_error="auto"`` (the estimate of
:mod:`dolfinode.global_error`, which warns above 10 x the tolerance, for runs of more than
one slab of small systems); ``--global-error`` solves every run with ``estimate_global_error=True``.
The summary counts the runs within the band that warned of the error at T (false alarms) and
those that warned of an error mid-run alone (M: real errors before T, which the run damps),
besides those above it without a warning.
"""
import argparse
import itertools
import json
import subprocess
import warnings
from pathlib import Path

import numpy as np

import dolfinode as dn
from dolfinode.bench import problems

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)")
TOLERANCES = tuple(10.0 ** -e for e in range(2, 11))
#: The out-of-sample check: methods and tolerances.
OUT_OF_SAMPLE_METHODS = ("cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)")
OUT_OF_SAMPLE_TOLERANCES = tuple(10.0 ** -e for e in range(3, 10))


def heat_problem(n=50, T=0.1):
    """A stiff linear system: the heat equation u_t = u_xx + 100 delta(x - 1/2) on (0, 1),
    u = 0 at both ends, as n central differences (eigenvalues -10 .. -1e4), from u = 0 to
    T = 0.1 (the slowest mode still decaying); exact solution by the matrix exponential."""
    h = 1.0 / (n + 1)
    L = (np.diag(-2.0 * np.ones(n)) + np.diag(np.ones(n - 1), 1)
         + np.diag(np.ones(n - 1), -1)) / h**2
    source = np.zeros(n)
    source[n // 2] = 100.0 / h
    ode, exact = problems.linear(L, np.zeros(n), T, b=source)
    return problems.Problem("heat", ode, stiff=True, final=exact(T), exact=exact,
                            reference="exact (matrix exponential)",
                            description=f"heat equation, {n} points, T = {T:g}")


def cases(multi_adaptive, sample="fitted"):
    """The calibration problems, with the multi-rate ones for multi-adaptive methods; or the
    problems the calibration was not fitted on (``sample="out-of-sample"``)."""
    if sample == "out-of-sample":
        return [problems.rober(), problems.pollu(), problems.vdpolm(), heat_problem()]
    chosen = [problems.hires_problem(), problems.vdpol(), problems.harmonic_problem()]
    if multi_adaptive:
        chosen += [problems.mass_spring_chain(), problems.seed_model(1e2)]
    return chosen


def delivered(problem, method, tolerance, calibrate, global_error="auto"):
    """(scaled error at T, time slabs, elements, how it warned) of a solve at ``tolerance``
    (with ``estimate_global_error=global_error``): True for a ToleranceWarning of the error
    at T, "mid-run" for one of an error before T alone, False for none; (inf, 0, 0, False)
    if it fails."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", dn.ToleranceWarning)
        try:
            sol = dn.solve(problem.ode, method=method, tolerance=tolerance,
                           absolute_tolerance=problem.atol_ratio * tolerance,
                           maximum_steps=2_000_000, calibrate_tolerance=calibrate,
                           estimate_global_error=global_error)
        except dn.SolverError:
            return float("inf"), 0, 0, False
    told = [str(w.message) for w in caught if issubclass(w.category, dn.ToleranceWarning)]
    midrun = [m for m in told
              if m.startswith(("the estimated error mid-run", "the measured error mid-run"))]
    warned = "mid-run" if told and len(midrun) == len(told) else bool(told)
    scored = list(problem.scored or range(problem.ode.N))
    final = problem.final[scored]
    error = np.max(np.abs(sol(problem.T)[scored] - final) / (problem.atol_ratio + np.abs(final)))
    return float(error), sol.stats["time slabs"], sol.stats["elements"], warned


#: The summary names at most this many runs above the band.
LISTED = 8


def summary(rows):
    """Lines counting the runs within [0.1, 10] x tolerance, the sweeps whose error grows
    more than 1.5x as the tolerance tightens, and the time slabs."""
    within = sum(0.1 <= r["error"] / r["tolerance"] <= 10 for r in rows)
    growing = []
    for key in dict.fromkeys((r["problem"], r["method"]) for r in rows):
        sweep = [r for r in rows if (r["problem"], r["method"]) == key]  # loosest first
        growing += [f"{key[1]} on {key[0]} at {b['tolerance']:.0e}" for a, b in
                    itertools.pairwise(sweep) if b["error"] > 1.5 * a["error"]]
    above = [r for r in rows if 10 < r["error"] / r["tolerance"] < float("inf")]
    silent = [f"{r['method']} on {r['problem']} at {r['tolerance']:.0e}: "
              f"{r['error'] / r['tolerance']:.3g} x" for r in above if not r.get("warned")]
    inside = [r for r in rows if 0.1 <= r["error"] / r["tolerance"] <= 10]
    failed = [f"{r['method']} on {r['problem']} at {r['tolerance']:.0e}" for r in rows
              if r["error"] == float("inf")]
    listed = "; ".join(silent[:LISTED]) + ("; ..." if len(silent) > LISTED else "")
    alarms = [f"{r['method']} on {r['problem']} at {r['tolerance']:.0e}: "
              f"{r['error'] / r['tolerance']:.3g} x" for r in inside if r.get("warned") is True]
    midrun = [f"{r['method']} on {r['problem']} at {r['tolerance']:.0e}" for r in inside
              if r.get("warned") == "mid-run"]
    estimated = sum(r.get("global_error") is True for r in rows)
    return [f"- runs within [0.1, 10] x tolerance: {within} of {len(rows)}",
            f"- runs above 10 x: {len(above)}, without a ToleranceWarning: {len(silent)}"
            + (f" ({listed})" if silent else ""),
            f"- runs within [0.1, 10] x with a ToleranceWarning (false alarms): {len(alarms)}"
            + (f" ({'; '.join(alarms)})" if alarms else "")
            + (f"; {estimated} runs with estimate_global_error=True" if estimated else ""),
            f"- runs within [0.1, 10] x at T warned of an error above 10 x mid-run (M): "
            f"{len(midrun)}" + (f" ({', '.join(midrun)})" if midrun else ""),
            f"- runs stopped by a SolverError: {len(failed)}"
            + (f" ({', '.join(failed)})" if failed else ""),
            f"- error growing > 1.5x as the tolerance tightens: {len(growing)}"
            + (f" ({', '.join(growing)})" if growing else ""),
            f"- time slabs, all runs: {sum(r['slabs'] for r in rows):,}"]


def tables(rows, tolerances):
    """Markdown lines: per problem, error / tolerance per method and tolerance (W: the run
    warned, fails: SolverError)."""
    lines = []
    methods = sorted({r["method"] for r in rows}, key=lambda m: (m.startswith("m"), m))
    for problem in dict.fromkeys(r["problem"] for r in rows):
        shown = [m for m in methods if any(r["problem"] == problem and r["method"] == m
                                           for r in rows)]
        lines += [f"## {problem}", "", "| tolerance | " + " | ".join(shown) + " |",
                  "|---|" + "---|" * len(shown)]
        for tolerance in tolerances:
            cells = []
            for method in shown:
                run = [r for r in rows if r["problem"] == problem and r["method"] == method
                       and r["tolerance"] == tolerance]
                if not run:
                    cells.append("")
                elif run[0]["error"] == float("inf"):
                    cells.append("fails")
                else:
                    cells.append(f"{run[0]['error'] / tolerance:.2g}"
                                 + {True: " W", "mid-run": " M"}.get(run[0].get("warned"), ""))
            lines.append(f"| {tolerance:.0e} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=str(ROOT / "doc" / "benchmarks"))
    parser.add_argument("--methods")
    parser.add_argument("--problems", choices=("fitted", "out-of-sample"), default="fitted")
    parser.add_argument("--uncalibrated", action="store_true")
    parser.add_argument("--global-error", action="store_true",
                        help="solve with estimate_global_error=True")
    args = parser.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True, check=False).stdout.strip()
    calibrate = not args.uncalibrated
    name = "tolerance" if calibrate else "tolerance_uncalibrated"
    out_of_sample = args.problems == "out-of-sample"
    methods = (args.methods or ",".join(OUT_OF_SAMPLE_METHODS if out_of_sample
                                        else METHODS)).split(",")
    tolerances = OUT_OF_SAMPLE_TOLERANCES if out_of_sample else TOLERANCES
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    record = output / f"{name}.json"
    old = json.loads(record.read_text()) if record.exists() else {"runs": []}
    chosen = cases(any(m.startswith("m") for m in methods), args.problems)
    redone = {(p.name, m) for p in chosen for m in methods}
    kept = [{"commit": old.get("commit"), **r} for r in old["runs"]
            if (r["problem"], r["method"]) not in redone]
    rows = []
    for problem in chosen:
        for method in methods:
            if problem.multiscale and not method.startswith("m"):
                continue
            for tolerance in tolerances:
                if method.endswith("(1)") and tolerance < 1e-7:
                    continue
                estimated = True if args.global_error else "auto"
                error, slabs, elements, warned = delivered(problem, method, tolerance,
                                                           calibrate, estimated)
                rows.append({"problem": problem.name, "method": method, "tolerance": tolerance,
                             "error": error, "slabs": slabs, "elements": elements,
                             "warned": warned, "commit": commit,
                             "sample": args.problems, "global_error": estimated})
                print(f"{problem.name:8} {method:6} tol {tolerance:.0e} error {error:.2e} "
                      f"ratio {error / tolerance:8.3g} elements {elements}"
                      + {True: " (warned)", "mid-run": " (warned mid-run)"}.get(warned, ""),
                      flush=True)
    rows = kept + rows
    record.write_text(json.dumps({"runs": rows}, indent=1) + "\n")
    report(rows, output / f"{name}.md", calibrate)


def report(rows, path, calibrate):
    """Write the markdown record of ``rows`` (summaries, then the tables) to ``path``."""
    fitted = [r for r in rows if r.get("sample", "fitted") == "fitted"]
    multi = [r for r in fitted if r["method"].startswith("m")]
    outside = [r for r in rows if r not in fitted]
    commits = ", ".join(dict.fromkeys(r["commit"] for r in rows))
    lines = ["# Delivered error against tolerance"
             + ("" if calibrate else " (calibrate_tolerance=False)"), "",
             ("error / tolerance at T (scaled as the Test Set's mescd; `benchmarks/"
             f"run_tolerance.py`, git {commits}); within [0.1, 10] is the target."), "",
             "Mono-adaptive methods, on the problems the mapping was fitted on:",
             *summary([r for r in fitted if r not in multi]), ""]
    if multi:
        lines += ["Multi-adaptive methods:", *summary(multi), ""]
    if outside:
        multi_outside = [r for r in outside if r["method"].startswith("m")]
        note = ("(`--problems out-of-sample`; W: the run raised a ToleranceWarning of the "
                "error at T, M: of an error mid-run alone):")
        lines += [f"Mono-adaptive methods on problems the mapping was not fitted on {note}",
                  *summary([r for r in outside if r not in multi_outside]), ""]
        if multi_outside:
            lines += [f"Multi-adaptive methods on problems the mapping was not fitted on {note}",
                      *summary(multi_outside), ""]
    lines += tables(fitted, TOLERANCES)
    if outside:
        lines += ["# Out of sample", "", *tables(outside, OUT_OF_SAMPLE_TOLERANCES)]
    path.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
