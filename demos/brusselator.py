"""A 2-D reaction-diffusion system declared one expression per component: the Brusselator.

On an n x n grid of the unit square (mirror boundaries, five-point Laplacian),

    u' = 1 + u^2 v - 4.4 u + alpha Lap u,    v' = 3.4 u - u^2 v + alpha Lap v,

from u = 0.5 + y, v = 1 + 5 x (the 2-D Brusselator of Hairer & Wanner, with Neumann instead
of periodic boundaries): N = 2 n^2 components, declared as sympy expressions in a loop over
the grid, as one would write it down. The right-hand sides take a handful of shapes (interior
points, edges and corners of each species), so dolfinode differentiates and compiles each
shape once (see "Compilation and cost" in the user guide) instead of N expressions. Prints
the lowering time and the shape count, solves with cG(2) and dG(2) (stiff: Newton's method,
with sparse LU factors of the Newton matrices on the larger grids), compares u(T) with
scipy's BDF (sparse Jacobian) at a tight tolerance, and plots u at T and u, v at the centre.

Run ``python demos/brusselator.py --help`` for the options.
"""
import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import scipy.sparse as sps
import sympy as sp
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode.compile import lower


def brusselator(n, alpha=0.02, T=10.0):
    """The ODE and the numpy right-hand side and Jacobian of the same system (for scipy)."""
    u = sp.symbols(f"u0:{n * n}")
    v = sp.symbols(f"v0:{n * n}")
    diffusion = sp.Symbol("alpha_over_h2")

    def laplacian(w, i, j):
        def at(a, b):  # mirror boundaries: the ghost point is the inner neighbour
            a = 1 if a < 0 else n - 2 if a > n - 1 else a
            b = 1 if b < 0 else n - 2 if b > n - 1 else b
            return w[a * n + b]
        return at(i - 1, j) + at(i + 1, j) + at(i, j - 1) + at(i, j + 1) - 4 * w[i * n + j]

    grid = [(i, j) for i in range(n) for j in range(n)]
    rhs = {}  # all u, then all v: the order of the states, and of u0
    for i, j in grid:
        k = i * n + j
        rhs[u[k]] = 1 + u[k] ** 2 * v[k] - 4.4 * u[k] + diffusion * laplacian(u, i, j)
    for i, j in grid:
        k = i * n + j
        rhs[v[k]] = 3.4 * u[k] - u[k] ** 2 * v[k] + diffusion * laplacian(v, i, j)
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="ij")
    u0 = np.concatenate([0.5 + y.ravel(), 1.0 + 5.0 * x.ravel()])
    coefficient = alpha * (n - 1) ** 2
    ode = dn.ODE(rhs, u0=u0, T=T, params={diffusion: coefficient}, nonnegative=True)

    second = sps.diags([1.0, -2.0, 1.0], [-1, 0, 1], shape=(n, n)).tolil()
    second[0, 1] = second[n - 1, n - 2] = 2.0
    lap = coefficient * (sps.kron(second, sps.eye(n)) + sps.kron(sps.eye(n), second)).tocsr()

    def f(t, w):
        a, b = w[:n * n], w[n * n:]
        return np.concatenate([1 + a * a * b - 4.4 * a + lap @ a, 3.4 * a - a * a * b + lap @ b])

    def jacobian(t, w):
        a, b = w[:n * n], w[n * n:]
        return sps.bmat([[lap + sps.diags(2 * a * b - 4.4), sps.diags(a * a)],
                         [sps.diags(3.4 - 2 * a * b), lap - sps.diags(a * a)]], format="csc")

    return ode, f, jacobian


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", default=Path(__file__).parent / "output", type=Path,
                        help="folder for the plot (default: demos/output)")
    parser.add_argument("--quick", action="store_true", help="12 x 12 grid to T = 2 (for tests)")
    parser.add_argument("--n", type=int, default=None, help="grid points per side (default 40)")
    parser.add_argument("--tolerance", type=float, default=1e-5, help="default: %(default)g")
    args = parser.parse_args(argv)
    n = args.n or (12 if args.quick else 40)
    T = 2.0 if args.quick else 10.0

    start = time.perf_counter()
    ode, f, jacobian = brusselator(n, T=T)
    declared = time.perf_counter() - start
    compiled = lower(ode)
    shapes = compiled.templates
    print(f"Brusselator on {n} x {n} points, N = {ode.N}: declared in {declared:.2f} s, "
          f"lowered in {compiled.compile_time:.2f} s "
          + (f"by shape ({shapes} shapes)" if shapes else "per expression"))

    start = time.perf_counter()
    reference = solve_ivp(f, (0.0, T), ode.u0, method="BDF", rtol=1e-9, atol=1e-9,
                          jac=jacobian)
    scipy_time = time.perf_counter() - start
    u_ref = reference.y[:, -1]
    print(f"scipy BDF at rtol = atol = 1e-9 (the reference): {scipy_time:.2f} s")
    results, sols = {}, {}
    for method in ("cG(2)", "dG(2)"):
        start = time.perf_counter()
        sol = sols[method] = dn.solve(ode, method, tolerance=args.tolerance)
        seconds = time.perf_counter() - start
        error = np.abs(sol.y[:, -1] - u_ref).max()
        results[method] = {"seconds": seconds, "error": error,
                           "steps": sol.stats["time slabs"], "newton": sol.stats["newton"],
                           "newton matrices": sol.stats["newton matrices"]}
        matrices = sol.stats["newton matrices"]
        print(f"{method}: {seconds:.3f} s (first solve), "
              f"{sol.stats['time slabs']} steps, newton {sol.stats['newton']}"
              + (f" ({matrices})" if matrices else "")
              + f", max |U(T) - reference| = {error:.2e}")

    args.output.mkdir(parents=True, exist_ok=True)
    plot = args.output / "brusselator.png"
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    sol = sols["cG(2)"]
    image = ax1.imshow(sol.y[:n * n, -1].reshape(n, n).T, origin="lower", extent=(0, 1, 0, 1))
    fig.colorbar(image, ax=ax1, label="u (concentration)")
    ax1.set(xlabel="x", ylabel="y", title=f"u at T = {T:g} (cG(2))")
    centre = (n // 2) * n + n // 2
    # at the element ends, which the step control places where u changes fast: equispaced
    # samples cut the peaks
    starts, steps = sol.time_steps()
    ends = np.append(starts, starts[-1] + steps[-1])
    values = sol(ends)
    ax2.plot(ends, values[centre], label="u (centre)")
    ax2.plot(ends, values[n * n + centre], label="v (centre)")
    ax2.set(xlabel="t", title=f"N = {ode.N}, tolerance {args.tolerance:g}, at the "
            f"{len(ends)} element ends")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(plot, dpi=120)
    plt.close(fig)
    print(f"plot: {plot}")
    return dict(results, plot=plot, shapes=shapes, N=ode.N,
                minimum=min(s.y.min() for s in sols.values()))


if __name__ == "__main__":
    main()
