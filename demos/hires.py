"""HIRES, a stiff problem from the Test Set for IVP Solvers, with dG(2).

Solves the HIRES system (8 components, "High Irradiance RESponse" of photomorphogenesis,
Hairer & Wanner) on [0, 321.8122] with adaptive dG(2) at a tolerance (default 1e-6, with
absolute tolerance equal to the relative one) and compares y(T) with the Test Set's
reference solution by the mixed-error significant correct digits
mescd = min_i -log10(|y_i - ref_i| / (atol/rtol + |ref_i|)) with atol/rtol = 1.
Prints y(T), the reference, the mescd and the solver statistics, and plots the 8
components on a logarithmic time axis (from t = 1e-3).

Run ``python demos/hires.py --help`` for the options.
"""
import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import dolfinode as dn
from dolfinode import problems

STATS = ("time slabs", "rejected steps", "f evaluations", "jacobian evaluations",
         "factorizations", "newton")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=Path(__file__).parent / "output", type=Path,
                        help="folder for the plot (default: demos/output)")
    parser.add_argument("--quick", action="store_true",
                        help="coarser plot (for tests); the solve is the same")
    parser.add_argument("--method", default="dG(2)", help="default: %(default)s")
    parser.add_argument("--tolerance", type=float, default=1e-6, help="default: %(default)g")
    args = parser.parse_args(argv)

    ode = problems.hires()
    start = time.perf_counter()
    sol = dn.solve(ode, method=args.method, tolerance=args.tolerance)
    wall = time.perf_counter() - start
    y = sol(ode.T)
    mescd = problems.mescd(y, problems.HIRES_REFERENCE, atol_over_rtol=1.0)

    print(f"HIRES on [0, {ode.T}] with {sol.method.name}, tolerance {args.tolerance:g}")
    print(f"{'':4}{'y(T)':>17}{'reference':>17}{'rel. error':>12}")
    for i, (yi, ri) in enumerate(zip(y, problems.HIRES_REFERENCE), start=1):
        print(f"y{i:<3}{yi:17.10e}{ri:17.10e}{abs(yi - ri) / abs(ri):12.2e}")
    print(f"  mescd (atol/rtol = 1) {mescd:.2f}")
    for name in STATS:
        print(f"  {name:22s}{sol.stats[name]}")
    print(f"  compile time {sol.stats['compile time']:.3g} s, solve time "
          f"{sol.stats['solve time']:.3g} s, wall time {wall:.3g} s")

    t = np.geomspace(1e-3, ode.T, 300 if args.quick else 2000)
    values = sol(t)
    args.output.mkdir(parents=True, exist_ok=True)
    plot = args.output / "hires.png"
    fig, axes = plt.subplots(2, 4, figsize=(13, 5.5), sharex=True)
    for i, ax in enumerate(axes.flat):
        ax.plot(t, values[i], lw=1)
        ax.plot(ode.T, problems.HIRES_REFERENCE[i], "k.", ms=5)
        ax.set_xscale("log")
        ax.set_title(f"y{i + 1}", fontsize=10)
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
    for ax in axes[1]:
        ax.set_xlabel("t")
    fig.suptitle(f"HIRES, {sol.method.name}, tolerance {args.tolerance:g}: "
                 f"{sol.stats['time slabs']} time slabs, mescd {mescd:.2f} (dot: reference)")
    fig.tight_layout()
    fig.savefig(plot, dpi=110)
    plt.close(fig)
    print(f"plot: {plot}")
    return {"y(T)": y, "mescd": mescd, "stats": sol.stats, "wall time": wall, "plot": plot}


if __name__ == "__main__":
    main()
