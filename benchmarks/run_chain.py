"""Mass-spring chain of 1000 masses with 10 springs 10^6 times stiffer (issue 3's second
headline measurement): mcG(1) and mcG(3) against cG(1), cG(3), scipy's DOP853 and LSODA at
equal accuracy.

The chain is ``dolfinode.bench.problems.mass_spring_chain``: unit masses between two walls,
unit springs, x_i(0) = sin(pi i / (n + 1)), v(0) = 0, linear, so the exact solution is the
matrix exponential (by eigendecomposition; good to about 5e-11). Every method sweeps its
tolerances (``TOLERANCES``: down to where it reaches 1e-9 or costs too much) with
``dolfinode.bench.runner.run_suite`` (median CPU time of repeated calls, compile time
apart); the time at equal accuracy is read off each method's error-time curve by log-log
interpolation, and where a method's loosest run is already more accurate, its fastest run's
time is used (marked *). The cost per f evaluation of every run is reported too.

Usage::

    .venv/bin/python benchmarks/run_chain.py [--n 1000] [--T 0.1] [--output doc/benchmarks]
"""
import argparse
import json
import time
from pathlib import Path

from run_reaction_front import time_at_error

from dolfinode.bench import report
from dolfinode.bench.problems import mass_spring_chain
from dolfinode.bench.runner import run_suite

#: Multi-adaptive methods, and what each is compared with (the best of them at each error).
MULTI = ("mcG(1)", "mcG(3)")
OTHERS = ("cG(1)", "cG(3)", "DOP853", "LSODA")
METHODS = MULTI + OTHERS
_LOW, _HIGH = [10.0**-k for k in range(3, 6)], [10.0**-k for k in range(3, 8)]
#: Tolerances of each method (second-order methods cost seconds per digit below 1e-5).
TOLERANCES = {"mcG(1)": _LOW, "cG(1)": _LOW, "LSODA": _LOW, "mcG(3)": _HIGH, "cG(3)": _HIGH,
              "DOP853": [10.0**-k for k in range(3, 13)]}


def time_at(rows, method, error):
    """(time, loosest) of ``method`` at max error ``error`` at T (see ``time_at_error``);
    when even its loosest run is more accurate, its fastest run's time and True."""
    points = [(r["err_T"], r["time_median_s"]) for r in rows
              if r["method"] == method and r["status"] == "ok" and r["time_median_s"]]
    if points and error > max(e for e, _ in points):
        return min(t for _, t in points), True
    return time_at_error(points, error), False


def plot(rows, path, title):
    """Work-precision diagram: max error at T against time, one line per method."""
    fig, ax = report.single_panel()
    for method in METHODS:
        pts = sorted((r["time_median_s"], r["err_T"]) for r in rows
                     if r["method"] == method and r["status"] == "ok" and r["time_median_s"])
        if pts:
            ax.loglog(*zip(*pts), marker="o", label=method)
    report.save_panel(fig, ax, path, title, "time [s]", "max error at T")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--T", type=float, default=0.1)
    parser.add_argument("--output", default=str(Path(__file__).resolve().parents[1] / "doc"
                                                / "benchmarks"))
    args = parser.parse_args(argv)
    problem = mass_spring_chain(n=args.n, stiffness=1e6, stiff_springs=10, T=args.T)
    rows = []
    for tolerances in {tuple(v) for v in TOLERANCES.values()}:
        methods = [m for m in METHODS if tuple(TOLERANCES[m]) == tolerances]
        rows += run_suite([problem], methods, list(tolerances), repeats=3, budget=5.0,
                          time_limit=120.0)[0]
    lines = [f"# Mass-spring chain: {args.n} masses, 10 springs 1e6 times stiffer, T = {args.T:g}",
             "", (f"`python benchmarks/run_chain.py --n {args.n} --T {args.T:g}`, "
                  f"{time.strftime('%Y-%m-%d')}; median CPU time of the solve call (shared "
                  "machine), max error at T against the matrix exponential."), "",
             ("| method | tolerance | time [s] | max error at T | steps / slabs | f evaluations "
             "| ns per f evaluation |"), "|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['method']} | {r['tolerance']:g} | {r['status']} | | | | |")
            continue
        ns = 1e9 * r["time_median_s"] / r["f_evals"] if r["f_evals"] else float("nan")
        lines.append(f"| {r['method']} | {r['tolerance']:g} | {r['time_median_s']:.3g} | "
                     f"{r['err_T']:.2e} | {r['steps']} | {r['f_evals']:,} | {ns:.3g} |")
    lines += ["", ("Time at equal accuracy (log-log interpolation; '-' where a method's runs do "
              "not reach the error; * its loosest run is more accurate, its fastest time); "
              f"the last columns divide the best of {', '.join(OTHERS)} by each multi-adaptive "
              "method:"), "",
              "| max error | " + " | ".join(METHODS) + "".join(f" | best / {m}" for m in MULTI)
              + " |", "|---" * (len(METHODS) + len(MULTI) + 1) + "|"]
    summary = []
    for err in [10.0**-k for k in range(2, 10)]:
        at = {m: time_at(rows, m, err) for m in METHODS}
        times = {m: t for m, (t, _) in at.items()}
        best = min((times[m] for m in OTHERS if times[m]), default=None)
        ratios = {m: best / times[m] if best and times[m] else None for m in MULTI}
        summary.append({"error": err, **times, "best other": best,
                        **{f"ratio {m}": r for m, r in ratios.items()}})
        lines.append(f"| {err:.0e} | " + " | ".join(f"{t:.3g}{'*' if loosest else ''}" if t
                                                     else "-" for t, loosest in at.values())
                     + "".join(f" | {r:.3g}x" if r else " | -" for r in ratios.values()) + " |")
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    plot(rows, out / "chain.png", f"{args.n}-mass chain, 10 springs 1e6 stiffer, T = {args.T:g}")
    lines += ["", "![work-precision](chain.png)"]
    for name, text in (("chain.md", "\n".join(lines) + "\n"),
                       ("chain.json", json.dumps({"rows": rows, "summary": summary},
                                                 indent=1, default=str))):
        tmp = out / (name + ".tmp")
        tmp.write_text(text)
        tmp.replace(out / name)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
