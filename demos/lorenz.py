"""The Lorenz system with an adaptive Galerkin method (DOLFIN's Lorenz demo).

Solves x' = sigma (y - x), y' = x (rho - z) - y, z' = x y - beta z with sigma = 10,
rho = 28, beta = 8/3 and u(0) = (1, 0, 0) up to T = 50 with cG(2) (or another method and
tolerance), prints the solver statistics and plots the trajectory in the x-z plane and x(t).
The plot evaluates the Galerkin solution itself (its exact piecewise polynomial) on a fine
grid, so no interpolation of output samples is involved.

Run ``python demos/lorenz.py --help`` for the options.
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

STATS = ("time slabs", "rejected steps", "f evaluations", "compile time", "solve time")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=Path(__file__).parent / "output", type=Path,
                        help="folder for the plot (default: demos/output)")
    parser.add_argument("--quick", action="store_true", help="short run to T = 10 (for tests)")
    parser.add_argument("--method", default="cG(2)", help="default: %(default)s")
    parser.add_argument("--tolerance", type=float, default=1e-8, help="default: %(default)g")
    parser.add_argument("--T", type=float, default=None, help="final time (default 50)")
    args = parser.parse_args(argv)

    ode = problems.lorenz(T=args.T or (10.0 if args.quick else 50.0))
    start = time.perf_counter()
    sol = dn.solve(ode, method=args.method, tolerance=args.tolerance)
    wall = time.perf_counter() - start

    print(f"Lorenz system on [0, {ode.T:g}] with {sol.method.name}, tolerance "
          f"{args.tolerance:g}")
    print(f"  u(T) = {np.array2string(sol(ode.T), precision=6)}")
    for name in STATS:
        value = sol.stats[name]
        print(f"  {name:16s} {value:.3g} s" if name.endswith(" time") else f"  {name:16s} {value}")
    print(f"  {'wall time':16s} {wall:.3g} s (solve call, including compilation)")

    t = np.linspace(ode.t0, ode.T, 200 * int(ode.T) + 1001)
    x, _, z = sol(t)
    args.output.mkdir(parents=True, exist_ok=True)
    plot = args.output / "lorenz.png"
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5), width_ratios=[1, 1.6])
    ax1.plot(x, z, lw=0.4)
    ax1.plot(x[0], z[0], "ko", ms=3)
    ax1.set(xlabel="x", ylabel="z", title="trajectory, x-z projection")
    ax2.plot(t, x, lw=0.7)
    ax2.set(xlabel="t", ylabel="x(t)",
            title=f"{sol.method.name}, tolerance {args.tolerance:g}, "
                  f"{sol.stats['time slabs']} time slabs")
    fig.tight_layout()
    fig.savefig(plot, dpi=120)
    plt.close(fig)
    print(f"plot: {plot}")
    return {"u(T)": sol(ode.T), "stats": sol.stats, "wall time": wall, "plot": plot}


if __name__ == "__main__":
    main()
