"""Probe the leading-term global error estimate on nonlinear problems (after the solve).

The estimate of doc/design/global_error.md, lead_n = J^m / m! (int_{I_n} (t_{n+1} - s)^m R(s) ds
+ k^m [U]_n), m = q (cG) or q + 1 (dG), R = U' - f(U), with J = df/du at U(t_{n+1}), summed
neutrally, sum_n |lead_n| (componentwise, scaled as benchmarks/run_tolerance.py), and the
same sum restricted to each slab's non-stiff modes (k |lambda| < 1 of J), and the
same sum with each slab's term damped by the stiff filter (I - k J / 2)^{-1} ... applied m times
as (I - k J / (m + 1))^{-m} (a bounded stand-in for e^{A (T - t)} on stiff modes). Prints the
error at T over the tolerance and each estimate over the error at T.

    python benchmarks/probe_global_error_nonlinear.py
"""
import sys
import warnings

import numpy as np
import sympy as sp

import dolfinode as dn
from dolfinode.bench import problems


def lagrange(nodes, x):
    return np.array([np.prod([(x - nodes[l]) / (nodes[j] - nodes[l])
                              for l in range(len(nodes)) if l != j]) for j in range(len(nodes))])


def dlagrange(nodes, x):
    n = len(nodes)
    return np.array([sum(np.prod([(x - nodes[l]) / (nodes[j] - nodes[l])
                                  for l in range(n) if l not in (j, i)]) / (nodes[j] - nodes[i])
                         for i in range(n) if i != j) for j in range(n)])


def probe(problem, method, tol):
    ode = problem.ode
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = dn.solve(ode, method=method, tolerance=tol,
                       absolute_tolerance=problem.atol_ratio * tol, maximum_steps=2_000_000)
    subs = {sp.Symbol(str(k)) if not isinstance(k, sp.Symbol) else k: v
            for k, v in dict(ode.params).items()} if ode.params else {}
    rhs = [sp.sympify(e).subs(subs) for e in ode.rhs]
    states = list(ode.states)
    f = sp.lambdify([states], rhs, "numpy")
    J = sp.lambdify([states], sp.Matrix(rhs).jacobian(states), "numpy")
    nodes = np.asarray(sol.method.nodes, dtype=float)
    gx, gw = np.polynomial.legendre.leggauss(len(nodes) + 3)
    gx, gw = (gx + 1) / 2, gw / 2
    B = np.array([lagrange(nodes, g) for g in gx])
    dB = np.array([dlagrange(nodes, g) for g in gx])
    start = lagrange(nodes, 0.0)
    is_dg = sol.method.family == "dG"
    m = sol.method.q + (1 if is_dg else 0)
    fact = float(np.prod(np.arange(1, m + 1)))
    vals, ks = sol.values, sol.k
    x = np.asarray(ode.u0, dtype=float)
    N = len(x)
    lead = np.zeros(N)
    damped = np.zeros(N)
    nonstiff = np.zeros(N)
    for n in range(len(ks)):
        k = ks[n]
        Ug = B @ vals[n]
        Rg = dB @ vals[n] / k - np.array([f(u) for u in Ug])
        mom = k ** (m + 1) * ((gw * (1 - gx) ** m) @ Rg)
        if is_dg:
            mom += k ** m * (start @ vals[n] - x)
        A = np.asarray(J(vals[n][-1]), dtype=float)
        v = mom / fact
        for _ in range(m):
            v = A @ v
        lead += np.abs(v)
        w = v
        M = np.eye(N) - k * A / (m + 1)
        for _ in range(m):
            w = np.linalg.solve(M, w)
        damped += np.abs(w)
        lam, V = np.linalg.eig(A)
        keep = k * np.abs(lam) < 1.0  # the slab's non-stiff modes only
        # filter before the products with J: the stiff modes' (k lambda)^m would swamp roundoff
        c = np.linalg.solve(V, mom / fact)[keep] * lam[keep] ** m
        nonstiff += np.abs((V[:, keep] @ c).real)
        x = vals[n][-1]
    scale = problem.atol_ratio + np.abs(problem.final)
    err = np.max(np.abs(vals[-1][-1] - problem.final) / scale)
    est = np.max(lead / scale)
    dam = np.max(damped / scale)
    ns = np.max(nonstiff / scale)
    print(f"{problem.name:9s} {method:6s} {tol:7.0e} slabs {len(ks):6d} err/tol {err / tol:9.3g} "
          f"lead/err {est / err:9.3g} damped/err {dam / err:9.3g} damped/tol {dam / tol:9.3g} "
          f"nonstiff/err {ns / err:9.3g}",
          flush=True)


def main():
    chosen = {"harmonic": problems.harmonic_problem, "chain": problems.mass_spring_chain,
              "hires": problems.hires_problem, "rober": problems.rober}
    names = sys.argv[1].split(",") if len(sys.argv) > 1 else list(chosen)
    for name in names:
        problem = chosen[name]()
        for method in ("cG(2)", "dG(2)"):
            for tol in (1e-3, 1e-5, 1e-7):
                try:
                    probe(problem, method, tol)
                except dn.SolverError as error:
                    print(f"{problem.name:9s} {method:6s} {tol:7.0e} failed: {error}"[:120])


if __name__ == "__main__":
    main()
