"""A stiff problem: the test equation u' = -1000 u with dG(1) and cG(1).

Solves u' = -1000 u, u(0) = 1 on [0, 10] (DOLFIN's stiff test problem 1, exact
u = exp(-1000 t)) with adaptive dG(1) and cG(1). After the initial transient the solution
is zero to within the tolerance and the time step grows by orders of magnitude, far beyond
the explicit stability limit k < 2/1000: the default nonlinear solver notices that the
fixed-point iteration fails to converge and switches to Newton's method. Prints the number
of steps, the rejected steps, whether Newton was used, the largest error at the element end
points (where the methods are superconvergent) and the error at a few times (between the end
points dG(q) is only of order q + 1, hence its larger errors in the transient); plots u(t)
and the step size k(t) on a logarithmic time axis.

Run ``python demos/stiff.py --help`` for the options.
"""
import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import dolfinode as dn
from dolfinode import problems


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=Path(__file__).parent / "output", type=Path,
                        help="folder for the plot (default: demos/output)")
    parser.add_argument("--quick", action="store_true", help="short run to T = 1 (for tests)")
    parser.add_argument("--methods", nargs="+", default=["dG(1)", "cG(1)"],
                        help="default: %(default)s")
    parser.add_argument("--tolerance", type=float, default=1e-6, help="default: %(default)g")
    parser.add_argument("--lam", type=float, default=1000.0, help="decay rate (default 1000)")
    parser.add_argument("--T", type=float, default=None, help="final time (default 10)")
    args = parser.parse_args(argv)

    ode, exact = problems.stiff_decay(lam=args.lam, T=args.T or (1.0 if args.quick else 10.0))
    times = np.array([1e-4, 1e-3, 1e-2, 0.1, ode.T])
    print(f"u' = -{args.lam:g} u on [0, {ode.T:g}], tolerance {args.tolerance:g}; "
          "errors |U(t) - exp(-lam t)|")
    print(f"{'method':>7} {'steps':>6} {'rejected':>8} {'newton':>6} {'nodal max':>10} |"
          + "".join(f"{f't={t:g}':>10}" for t in times))
    results, sols = {}, {}
    for method in args.methods:
        sol = sols[method] = dn.solve(ode, method=method, tolerance=args.tolerance)
        t_start, k = sol.time_steps()
        nodes = t_start + k  # element end points, where the methods are superconvergent
        errors = np.abs(sol(times)[0] - exact(times)[0])
        results[method] = {
            "steps": sol.stats["time slabs"], "rejected": sol.stats["rejected steps"],
            "newton": sol.stats["newton"], "errors": dict(zip(times, errors)),
            "nodal error": np.abs(sol(nodes)[0] - exact(nodes)[0]).max(),
            "largest step": k.max()}
        r = results[method]
        print(f"{method:>7} {r['steps']:6d} {r['rejected']:8d} {r['newton']!s:>6} "
              f"{r['nodal error']:10.2e} |" + "".join(f"{e:10.2e}" for e in errors))

    args.output.mkdir(parents=True, exist_ok=True)
    plot = args.output / "stiff.png"
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    t = np.geomspace(1e-6 * ode.T, ode.T, 2000)
    ax1.semilogx(t, exact(t)[0], "k", lw=3, alpha=0.3, label="exact exp(-1000 t)")
    for method, sol in sols.items():
        t_start, k = sol.time_steps()
        ax1.semilogx(t, sol(t)[0], lw=1, label=method)
        ax2.loglog(t_start + k, k, ".-", ms=3, lw=0.8, label=f"{method} ({len(k)} steps)")
    ax2.axhline(2.0 / args.lam, color="gray", ls=":", label="explicit Euler limit 2/lam")
    ax1.set(xlabel="t", ylabel="u(t)", title="solution")
    ax2.set(xlabel="t (end of step)", ylabel="time step k",
            title=f"adaptive steps, tolerance {args.tolerance:g}")
    for ax in (ax1, ax2):
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(plot, dpi=120)
    plt.close(fig)
    print(f"plot: {plot}")
    return dict(results, plot=plot)


if __name__ == "__main__":
    main()
