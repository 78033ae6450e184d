"""Order of accuracy of cG(q) and dG(q) on the harmonic oscillator.

Solves u'' = -u (as u' = v, v' = -u, u(0) = 0, v(0) = 1, exact u = sin t) over
[0, 4 pi] with uniform time steps k = T/4, T/8, ... (``fixed_time_step=True``), and
compares the error at T with the theoretical nodal (superconvergent) order of each method:
2q for cG(q) and 2q + 1 for dG(q). The observed order between two successive steps is
log2(e(2k) / e(k)); errors at the rounding level are skipped. Prints the tables and saves
a log-log plot of the error against k.

Run ``python demos/harmonic.py --help`` for the options.
"""
import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import dolfinode as dn
from dolfinode import problems

METHODS = [f"cG({q})" for q in range(1, 6)] + [f"dG({q})" for q in range(6)]


def observed_orders(errors, floor):
    """log2 of successive error ratios; nan where either error is below ``floor``."""
    e = np.asarray(errors)
    valid = (e[:-1] > floor) & (e[1:] > floor)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(valid, np.log2(e[:-1] / e[1:]), np.nan)


def convergence(method, ode, exact, steps):
    """Max-norm errors at T for uniform steps T/n, n in ``steps``; also returns the order."""
    errors = []
    for n in steps:
        sol = dn.solve(ode, method=method, fixed_time_step=True,
                       initial_time_step=(ode.T - ode.t0) / n)
        errors.append(np.max(np.abs(sol(ode.T) - exact(ode.T))))
    return np.array(errors), sol.method.order


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=Path(__file__).parent / "output", type=Path,
                        help="folder for the plot (default: demos/output)")
    parser.add_argument("--quick", action="store_true", help="fewer step sizes (for tests)")
    parser.add_argument("--methods", nargs="+", default=METHODS, help="default: %(default)s")
    parser.add_argument("--T", type=float, default=4 * np.pi, help="final time (default 4 pi)")
    parser.add_argument("--levels", type=int, default=None,
                        help="number of halved steps, starting at T/4 (default 11, quick 8)")
    parser.add_argument("--floor", type=float, default=1e-11,
                        help="errors below this are rounding, skipped for the orders "
                             "(default %(default)g)")
    args = parser.parse_args(argv)

    ode, exact = problems.harmonic(T=args.T)
    levels = args.levels or (8 if args.quick else 11)
    steps = 4 * 2 ** np.arange(levels)
    k = (ode.T - ode.t0) / steps
    errors, orders, theory = {}, {}, {}
    for method in args.methods:
        errors[method], theory[method] = convergence(method, ode, exact, steps)
        rates = observed_orders(errors[method], args.floor)
        orders[method] = rates
    observed = {m: (r[np.isfinite(r)][-1] if np.isfinite(r).any() else np.nan)
                for m, r in orders.items()}

    print(f"Harmonic oscillator on [0, {ode.T:.4g}], uniform steps k = T/n, "
          f"max error at T (errors < {args.floor:g} are rounding)")
    print(f"{'n':>7}" + "".join(f"{n:>9d}" for n in steps))
    for m in args.methods:
        print(f"{m:>7}" + "".join(f"{e:9.1e}" for e in errors[m]))
    print("\nObserved order log2(e(2k)/e(k)) between successive n; the estimate is the one "
          "at the smallest k above the floor")
    print(f"{'method':>7} {'theory':>6} {'observed':>8} |" + "".join(
        f"{n:>6d}" for n in steps[1:]))
    for m in args.methods:
        rates = "".join("    --" if np.isnan(r) else f"{r:6.2f}" for r in orders[m])
        print(f"{m:>7} {theory[m]:6d} {observed[m]:8.2f} |{rates}")

    args.output.mkdir(parents=True, exist_ok=True)
    plot = args.output / "harmonic_convergence.png"
    fig, ax = plt.subplots(figsize=(8.5, 5.5))
    colors = plt.cm.plasma(np.linspace(0, 0.85, 6))
    for m in args.methods:
        q = int(m[3:-1])
        ax.loglog(k, errors[m], "o-" if m.startswith("cG") else "s--", ms=3, color=colors[q],
                  label=f"{m}, order {theory[m]}")
    ax.axhline(args.floor, color="gray", lw=0.8, ls=":", label="rounding floor")
    ax.set(xlabel="time step k", ylabel="max |U(T) - u(T)|",
           title="Harmonic oscillator: error at T = 4$\\pi$ vs k")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1))
    ax.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    fig.savefig(plot, dpi=120)
    plt.close(fig)
    print(f"\nplot: {plot}")
    return {"k": k, "errors": errors, "orders": observed, "rates": orders, "theory": theory,
            "plot": plot}


if __name__ == "__main__":
    main()
