"""Mass-spring chain of 1000 masses with 10 springs 10^6 times stiffer (issue 3's second
headline measurement): mcG(1) against cG(1), scipy's DOP853 and LSODA at equal accuracy.

The chain is ``dolfinode.bench.problems.mass_spring_chain``: unit masses between two walls,
unit springs, x_i(0) = sin(pi i / (n + 1)), v(0) = 0, linear, so the exact solution is the
matrix exponential (by eigendecomposition). Every method sweeps the tolerances with
``dolfinode.bench.runner.run_suite`` (median wall time of repeated calls, compile time
apart); the time at equal accuracy is read off each method's error-time curve by log-log
interpolation at the error levels that every method reaches. The cost per element and per
f evaluation of the dolfinode runs are reported too.

Usage::

    .venv/bin/python benchmarks/run_chain.py [--n 1000] [--T 1] [--tolerances 1e-3,...]
        [--output doc/benchmarks]
"""
import argparse
import json
import time
from pathlib import Path

from run_reaction_front import time_at_error

from dolfinode.bench import report
from dolfinode.bench.problems import mass_spring_chain
from dolfinode.bench.runner import run_suite

METHODS = ("mcG(1)", "cG(1)", "DOP853", "LSODA")


def time_at(rows, method, error):
    """The time of ``method`` at max error ``error`` at T (see ``time_at_error``)."""
    return time_at_error([(r["err_T"], r["time_median_s"]) for r in rows
                          if r["method"] == method and r["status"] == "ok"
                          and r["time_median_s"]], error)


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
    parser.add_argument("--T", type=float, default=1.0)
    parser.add_argument("--tolerances", default="1e-3,1e-4,1e-5,1e-6,1e-7")
    parser.add_argument("--output", default=str(Path(__file__).resolve().parents[1] / "doc"
                                                / "benchmarks"))
    args = parser.parse_args(argv)
    problem = mass_spring_chain(n=args.n, stiffness=1e6, stiff_springs=10, T=args.T)
    tolerances = [float(v) for v in args.tolerances.split(",")]
    rows, _ = run_suite([problem], list(METHODS), tolerances, repeats=3, budget=5.0,
                        time_limit=120.0)
    lines = [f"# Mass-spring chain: {args.n} masses, 10 springs 1e6 times stiffer, T = {args.T:g}",
             "", (f"`python benchmarks/run_chain.py --n {args.n} --T {args.T:g}`, "
                  f"{time.strftime('%Y-%m-%d')}; median wall time of the solve call (shared "
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
    levels = [10.0 ** -k for k in range(2, 10)]
    lines += ["", ("Time at equal accuracy (log-log interpolation; '-' where a method's runs do "
              "not reach the error):"), "", "| max error | " + " | ".join(METHODS)
              + " | best scipy / mcG(1) |", "|---" * (len(METHODS) + 2) + "|"]
    summary = []
    for err in levels:
        times = {m: time_at(rows, m, err) for m in METHODS}
        scipy_times = [times[m] for m in ("DOP853", "LSODA") if times[m]]
        ratio = (min(scipy_times) / times["mcG(1)"]) if scipy_times and times["mcG(1)"] else None
        if not any(times.values()):
            continue
        summary.append({"error": err, **times, "ratio": ratio})
        lines.append(f"| {err:.0e} | " + " | ".join(f"{times[m]:.3g}" if times[m] else "-"
                                                     for m in METHODS)
                     + f" | {ratio:.3g}x |" if ratio else " | - |")
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
