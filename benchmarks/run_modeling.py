"""Cost of the simple model against kappa: automatic modeling beside scipy on the full model.

For kappa = 1e4 ... 1e18 (tau = 100 / sqrt(kappa), cG(2), tolerance 1e-4): wall time (best of
``--repeat``) and elements with automatic modeling, and the wall time and steps of scipy's
DOP853 and LSODA (rtol 1e-6, atol 1e-9) on the full model over [0, 100], each stopped after
``--cap`` seconds (then reported as not finished). Writes doc/benchmarks/modeling.{md,csv,png}.

``--lattice``: instead, the paper's figure 5 (the lattice with m = 1e-4, tau = 1, T = 100,
p = 3 and 5): max |D - D-bar| on [2 tau, T] against the full model's averaged diameter
(DOP853), for the default subgrid model (auto: affine after the first rebuild), the constant
model rebuilt at the control points, and the constant model built once; CPU times.
Writes doc/benchmarks/modeling_lattice.md.
"""
import argparse
import csv
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode.bench.report import machine_info
from dolfinode.compile import lower

sys.path.insert(0, str(Path(__file__).parents[1] / "demos"))
from lattice import lattice, reference
from simple_model import simple_model


class _Timeout(Exception):
    pass


def scipy_cost(ode, method, cap):
    compiled = lower(ode)
    start = time.perf_counter()

    def f(t, u):
        if time.perf_counter() - start > cap:
            raise _Timeout
        return compiled.f(u, t)

    try:
        sol = solve_ivp(f, (0.0, ode.T), ode.u0, method=method, rtol=1e-6, atol=1e-9)
    except _Timeout:
        return None, None, None
    t = np.linspace(0, ode.T, 2001)
    error = np.max(np.abs(np.interp(t, sol.t, sol.y[0]) - (1 - np.cos(t)) / 4))
    return time.perf_counter() - start, sol.t.size, error


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cap", type=float, default=60.0, help="seconds per scipy run")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--output", type=Path, default=Path(__file__).parents[1] / "doc" / "benchmarks")
    parser.add_argument("--lattice", action="store_true",
                        help="the lattice comparison (figure 5) instead of the kappa sweep")
    args = parser.parse_args(argv)
    if args.lattice:
        return lattice_drift(args.output)
    rows = []
    for exponent in (4, 6, 8, 10, 12, 14, 16, 18):
        kappa = 10.0 ** exponent
        ode = simple_model(kappa)
        walls = []
        for _ in range(args.repeat):
            start = time.perf_counter()
            sol = dn.solve(ode, method="cG(2)", tolerance=1e-4, automatic_modeling=True,
                           average_length=100 / np.sqrt(kappa))
            walls.append(time.perf_counter() - start)
        t = np.linspace(0, 100, 2001)
        row = {"kappa": kappa, "modeling wall [s]": min(walls),
               "modeling elements": sol.stats["elements"],
               "modeling max|U1-(1-cos t)/4|": np.max(np.abs(sol(t)[0] - (1 - np.cos(t)) / 4))}
        for method in ("DOP853", "LSODA"):
            wall, steps, error = scipy_cost(ode, method, args.cap)
            row[f"{method} wall [s]"], row[f"{method} steps"] = wall, steps
            row[f"{method} max|u1-(1-cos t)/4|"] = error
        print(row, flush=True)
        rows.append(row)
    args.output.mkdir(parents=True, exist_ok=True)
    with open(args.output / "modeling.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    kappas = [r["kappa"] for r in rows]
    ax.loglog(kappas, [r["modeling wall [s]"] for r in rows], "o-", label="dolfinode, automatic modeling")
    for method in ("DOP853", "LSODA"):
        done = [(r["kappa"], r[f"{method} wall [s]"]) for r in rows if r[f"{method} wall [s]"]]
        if done:
            ax.loglog(*zip(*done), "s--", label=f"scipy {method}, full model")
    ax.axhline(args.cap, color="gray", ls=":", label=f"scipy cap {args.cap:g} s")
    ax.set(xlabel="kappa", ylabel="wall time [s]", title="simple model on [0, 100]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.output / "modeling.png", dpi=110)
    meta = machine_info()
    lines = ["# Automatic modeling: cost of the simple model against kappa", "",
             f"Measured {meta['date']} (git {meta['git_commit']}) on {meta['cpu']}, "
             f"{meta['cpu_count']} CPUs.", "",
             ("`python benchmarks/run_modeling.py` (cG(2), tolerance 1e-4, tau = 100/sqrt(kappa), "
              f"best of {args.repeat}; scipy rtol 1e-6, atol 1e-9, capped at {args.cap:g} s; "
              "'-' = not finished)."), "",
             ("| kappa | modeling wall [s] | elements | max err U1 | DOP853 wall [s] | DOP853 steps "
              "| LSODA wall [s] | LSODA steps |"), "|---|---|---|---|---|---|---|---|"]
    fmt = lambda v, f: "-" if v is None else format(v, f)
    for r in rows:
        lines.append(f"| {r['kappa']:.0e} | {r['modeling wall [s]']:.2f} | "
                     f"{r['modeling elements']} | {r['modeling max|U1-(1-cos t)/4|']:.1e} | "
                     f"{fmt(r['DOP853 wall [s]'], '.2f')} | {fmt(r['DOP853 steps'], 'd')} | "
                     f"{fmt(r['LSODA wall [s]'], '.2f')} | {fmt(r['LSODA steps'], 'd')} |")
    lines += ["", "![cost against kappa](modeling.png)", ""]
    (args.output / "modeling.md").write_text("\n".join(lines))


def lattice_drift(output, T=100.0, tau=1.0, m=1e-4):
    """The lattice of figure 5: drift of the reduced diameter from the averaged full one."""
    models = {"auto (default)": {},
              "constant, rebuilt": {"subgrid_model": "constant"},
              "constant, built once": {"subgrid_model": "constant", "rebuild_model": False,
                                       "control_points": 0}}
    lines = ["# Automatic modeling: the lattice of figure 5", "",
             (f"`python benchmarks/run_modeling.py --lattice`: m = {m:g}, tau = {tau:g}, "
              f"T = {T:g}, cG(2), tolerance 1e-4, 10 control points (default), "
              "model_tolerance 0.02 (default). D-bar: the full model's diameter (scipy DOP853, "
              "rtol 1e-8) averaged with the modeling kernel of length tau. CPU seconds (process "
              "time, kernels cached; the first row includes loading them)."), "",
             ("| p | N | subgrid model | max abs(D - D-bar) on [2 tau, T] | builds | elements "
              "| CPU [s] | contraction of D-bar | DOP853 CPU [s] |"),
             "|---|---|---|---|---|---|---|---|---|"]
    for p in (3, 5):
        lat = lattice(p, m, T=T)
        start = time.process_time()
        times, _, D_bar, _ = reference(lat, T, tau)
        reference_cpu = time.process_time() - start
        after = times >= 2 * tau
        for name, options in models.items():
            start = time.process_time()
            sol = dn.solve(lat.ode, method="cG(2)", tolerance=1e-4, automatic_modeling=True,
                           average_length=tau, **options)
            cpu = time.process_time() - start
            drift = np.max(np.abs(lat.diameter(sol(times[after])) - D_bar[after]))
            line = (f"| {p} | {lat.ode.N} | {name} | {drift:.4f} | {len(sol.model.built)} | "
                    f"{sol.stats['elements']} | {cpu:.1f} | {np.sqrt(2) - D_bar.min():.4f} | "
                    f"{reference_cpu:.1f} |")
            print(line, flush=True)
            lines.append(line)
    lines.append("")
    output.mkdir(parents=True, exist_ok=True)
    (output / "modeling_lattice.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
