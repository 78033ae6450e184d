"""ROBER to t = 1e11: a stiff problem where a loose absolute tolerance returns garbage.

Robertson's chemical kinetics (Test Set for IVP Solvers)

    y1' = -0.04 y1 + 1e4 y2 y3,  y2' = 0.04 y1 - 1e4 y2 y3 - 3e7 y2^2,  y3' = 3e7 y2^2,

on [0, 1e11] from y = (1, 0, 0). y2 stays below 3.7e-5 and falls to 8e-14, so an absolute
tolerance of 1e-6 does not resolve it: a y2 of -4e-6 is "within tolerance", 1e4 y2 y3 then
drives y1 below zero, and the solution follows the branch y1 = -y3 that grows without
bound. Solved four ways:

* scipy's BDF at rtol = atol = 1e-6 (reported as it comes; scipy 1.17 returns success
  with y1 ~ -3e7);
* dolfinode dG(2) at the same tolerances (L-stable: the stiff error is damped);
* dolfinode mcG(2) at tolerance = atol = 1e-3, with the concentrations undeclared (the same
  garbage) and declared ``nonnegative=True`` (a step that takes one below -atol is rejected,
  accepted values in [-atol, 0) are set to 0).

Prints y(T) against the reference and plots y1 on a logarithmic time axis.
Run ``python demos/rober.py --help`` for the options.
"""
import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode.bench.problems import ROBER_REFERENCE

y1, y2, y3 = sp.symbols("y1 y2 y3")
RHS = {y1: -0.04 * y1 + 1e4 * y2 * y3,
       y2: 0.04 * y1 - 1e4 * y2 * y3 - 3e7 * y2**2,
       y3: 3e7 * y2**2}
T = 1e11


def rober(nonnegative=False):
    return dn.ODE(RHS, u0=[1.0, 0.0, 0.0], T=T, nonnegative=nonnegative)


def scipy_bdf(tol):
    """scipy's BDF with the exact Jacobian, lambdified from the same expressions."""
    states = list(RHS)
    f = sp.lambdify(states, list(RHS.values()))
    jac = sp.lambdify(states, sp.Matrix(list(RHS.values())).jacobian(states))
    return solve_ivp(lambda t, y: f(*y), (0.0, T), [1.0, 0.0, 0.0], method="BDF", rtol=tol,
                     atol=tol, jac=lambda t, y: jac(*y), dense_output=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=Path(__file__).parent / "output", type=Path,
                        help="folder for the plot (default: demos/output)")
    parser.add_argument("--quick", action="store_true",
                        help="coarser plot (for tests); the solves are the same")
    args = parser.parse_args(argv)

    bdf = scipy_bdf(1e-6)
    runs = {"dG(2), tol = atol = 1e-6": dn.solve(rober(), "dG(2)", tolerance=1e-6),
            "mcG(2), tol = atol = 1e-3": dn.solve(rober(), "mcG(2)", tolerance=1e-3),
            "mcG(2), tol = atol = 1e-3, nonnegative": dn.solve(rober(nonnegative=True),
                                                               "mcG(2)", tolerance=1e-3)}
    final = {"scipy BDF, rtol = atol = 1e-6": bdf.y[:, -1]}
    final.update({name: sol(T) for name, sol in runs.items()})

    print(f"ROBER on [0, {T:g}]; scipy BDF reports success = {bdf.success}")
    print(f"{'':42}{'y1(T)':>13}{'y2(T)':>13}{'y3(T)':>13}")
    print(f"{'reference':42}" + "".join(f"{v:13.4e}" for v in ROBER_REFERENCE))
    for name, y in final.items():
        print(f"{name:42}" + "".join(f"{v:13.4e}" for v in y))
    for name, sol in runs.items():
        print(f"  {name}: {sol.stats['time slabs']} slabs, {sol.stats['elements']} elements, "
              f"{sol.stats['rejected steps']} rejected, solve {sol.stats['solve time']:.3g} s")

    t = np.geomspace(1e-5, T, 200 if args.quick else 1000)
    args.output.mkdir(parents=True, exist_ok=True)
    plot = args.output / "rober.png"
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax.plot(t, bdf.sol(t)[0], lw=1, label="scipy BDF, rtol = atol = 1e-6")
    for name, sol in runs.items():
        ax.plot(t, sol(t)[0], lw=1, label=name)
    ax.plot(T, ROBER_REFERENCE[0], "k.", ms=6, label="reference y1(T)")
    ax.set_xscale("log")
    ax.set_yscale("symlog", linthresh=1e-8)
    ax.set_xlabel("t")
    ax.set_ylabel("y1")
    ax.set_title("ROBER: y1 (symmetric log scale)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(plot, dpi=110)
    plt.close(fig)
    print(f"plot: {plot}")
    return {"y(T)": final, "solutions": runs, "plot": plot}


if __name__ == "__main__":
    main()
