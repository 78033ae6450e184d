"""The seed paper's simple model problem, solved with automatic modeling.

Jansson, Johnson & Logg, "Computational modeling of dynamical systems" (2005), section 2:

    u1'' + u1 - u2^2 / 2 = 0,   u2'' + kappa u2 = 0,   u(0) = (0, 1),  u'(0) = (0, 0),

on [0, 100] with kappa = 1e18: u2 oscillates on the time scale 1e-9 and pushes u1 with the
average force u2^2 / 2 = 1/4, so u1 is close to (1 - cos t) / 4 (exactly
u1 = (1 - cos t)/4 + A (cos(2 sqrt(kappa) t) - cos t), A = -1/(4 (4 kappa - 1))). Resolving
u2 over [0, 100] would take ~1e12 steps; automatic modeling resolves [0, 2 tau] only, builds
the reduced model u1'' + u1 - g~ = 0 with u2 inactivated, and checks it at control points.

Prints g~_1 (the subgrid model of the u1 equation) and max |U1(t) - (1 - cos t)/4| over
[0, 100], and plots the paper's figure 2: u1 and u2 on [0, 100] and on [0, 4e-7].

Run ``python demos/simple_model.py --help`` for the options.
"""
import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import sympy as sp

import dolfinode as dn


def simple_model(kappa=1e18, T=100.0):
    """The ODE declaration; components (u1, u2, u1', u2')."""
    u1, u2, k = sp.symbols("u1 u2 kappa")
    return dn.ODE.second_order({u1: -u1 + u2 ** 2 / 2, u2: -k * u2}, x0={u1: 0.0, u2: 1.0},
                               v0={u1: 0.0, u2: 0.0}, T=T, params={k: kappa})


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=Path(__file__).parent / "output", type=Path,
                        help="folder for the plot (default: demos/output)")
    parser.add_argument("--quick", action="store_true",
                        help="coarser plot (for tests); the solve is the same")
    parser.add_argument("--kappa", type=float, default=1e18, help="default: %(default)g")
    parser.add_argument("--tau", type=float, default=1e-7,
                        help="average length; 0: chosen by the solver (default %(default)g)")
    parser.add_argument("-T", type=float, default=100.0, help="default: %(default)g")
    parser.add_argument("--method", default="cG(2)", help="default: %(default)s")
    parser.add_argument("--tolerance", type=float, default=1e-4, help="default: %(default)g")
    args = parser.parse_args(argv)

    ode = simple_model(args.kappa, args.T)
    start = time.perf_counter()
    sol = dn.solve(ode, method=args.method, tolerance=args.tolerance, automatic_modeling=True,
                   average_length=args.tau or None)
    wall = time.perf_counter() - start
    u1_dot = ode.velocity(ode.states[0])
    g1 = sol.model.g[u1_dot]
    t = np.linspace(0.0, args.T, 2001 if args.quick else 20001)
    error = np.max(np.abs(sol(t)[0] - (1 - np.cos(t)) / 4))
    tau = sol.model.average_length
    print(f"simple model, kappa = {args.kappa:g}, tau = {tau:g}, {sol.method.name}, tolerance "
          f"{args.tolerance:g}")
    print(f"  g~_1 = {g1:.8f} (1/4 - g~_1 = {0.25 - g1:.2e})")
    print(f"  max |U1(t) - (1 - cos t)/4| on [0, {args.T:g}] = {error:.2e}")
    print(f"  inactive: {', '.join(s.name for s in sol.model.inactive)}; model built at "
          f"t = {sol.model.built}; {len(sol.model.control_points)} control points, largest "
          f"defect |g~ - g-bar| = {sol.model.largest_defect:.2e}")
    print(f"  {sol.stats['elements']} elements, {sol.stats['time slabs']} time slabs, "
          f"{wall:.2f} s")
    estimate = sol.model.modeling_error({sol.ode.states[0]: 1.0})
    print(f"  goal u1(T): modeling error <= S0 max |g~ - g-bar| = {estimate.S0:.4g} x "
          f"{estimate.largest_defect:.2e} = {estimate.bound:.2e}; discretisation error "
          f"estimate {estimate.discretization:.2e}")

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6.5))
    values = sol(t)
    ax1.plot(t, values[0], label="u1")
    ax1.plot(t, (1 - np.cos(t)) / 4, "k:", lw=0.8, label="(1 - cos t) / 4")
    ax1.plot(t, values[1], label="u2 (after tau: its average, u2 inactive)")
    ax1.set(xlabel="t", title=f"simple model, kappa = {args.kappa:g}, tau = {tau:g}: "
            f"g~_1 = {g1:.6f}")
    ax1.legend(loc="upper right")
    early = np.linspace(0.0, 4 * tau, 400 if args.quick else 4000)
    values = sol(early)
    ax2.plot(early, values[0], label="u1")
    ax2.plot(early, values[1], label="u2 (resolved up to tau, then its average)")
    ax2.axvline(tau, color="k", ls=":", lw=0.8)
    ax2.set(xlabel="t", title="on [0, 4 tau]: the reduced model takes over at t = tau")
    ax2.legend(loc="upper right")
    fig.tight_layout()
    args.output.mkdir(parents=True, exist_ok=True)
    plot = args.output / "simple_model.png"
    fig.savefig(plot, dpi=110)
    plt.close(fig)
    print(f"plot: {plot}")
    return {"g1": g1, "error": error, "solution": sol, "wall time": wall, "plot": plot,
            "modeling error": estimate}


if __name__ == "__main__":
    main()
