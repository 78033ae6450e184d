"""Probe for a global error estimate of mono-adaptive runs, on linear problems u' = A u + b.

For each accepted slab n of a run (cG(q), dG(q), calibrated tolerance) it computes

- d_n = U_{n+1} - e^{A k_n} U_n (source included): the exact local nodal error;
- lead_n = A^m / m! (int_{I_n} (t_{n+1} - s)^m R(s) ds + k_n^m [U]_n (dG only)), m = q (cG)
  or q + 1 (dG), with R = U' - A U - b: the leading term of
  d_n = e^{A k} [U]_n + int_{I_n} e^{A (t_{n+1} - s)} R(s) ds once Galerkin orthogonality
  removes the terms of degree below m (m products with A, what a loop could afford with J);
- r_n = k_n (U'(t_{n+1}^-) - f(U_{n+1})): the step estimate before the stiff filter.

and prints, scaled as benchmarks/run_tolerance.py (atol_ratio + |u(T)|): the error at T over
the tolerance, and the neutral sums sum_n |d_n|, sum_n |lead_n|, sum_n |r_n| over the error
at T (one estimate is good if its ratio is about constant over problems, methods and
tolerances), the 10-90 % range of |lead_n| / |d_n| per slab, and the power p of a fit
|d_n| ~ c |r_n|^p. doc/design/global_error.md has the results.

    python benchmarks/probe_global_error.py
"""
import warnings

import numpy as np

import dolfinode as dn
from dolfinode.bench import problems


def lagrange_end_derivative(nodes):
    """Weights w_j with p'(1) = sum_j w_j p(tau_j) for the interpolant on ``nodes``."""
    nodes = np.asarray(nodes, dtype=float)
    V = np.vander(nodes, increasing=True)
    powers = np.arange(len(nodes))
    dmono = powers * 1.0 ** np.maximum(powers - 1, 0)
    return np.linalg.solve(V.T, dmono)


def probe(name, A, b, u0, T, method, tol, atol_ratio):
    n = len(u0)
    sym = __import__("sympy").symbols(f"u0:{n}")
    rhs = {sym[i]: sum(A[i, j] * sym[j] for j in range(n) if A[i, j]) + b[i] for i in range(n)}
    ode = dn.ODE(rhs, u0=u0, T=T)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = dn.solve(ode, method=method, tolerance=tol, absolute_tolerance=atol_ratio * tol)
    w, V = np.linalg.eig(A)
    Vi = np.linalg.inv(V)
    shift = np.linalg.solve(A, b)

    def flow(k, x):
        return (V @ (np.exp(w * k) * (Vi @ (x + shift)))).real - shift

    nodes = np.asarray(sol.method.nodes)
    wend = lagrange_end_derivative(nodes)
    vals = sol.values  # (M, q+1, N) at t_start + tau_j k
    ks = sol.k
    M = len(ks)
    x = np.asarray(u0, dtype=float)
    ends = vals[:, -1, :]
    # the leading term of d_n = int_{I_n} e^{A (t_{n+1} - s)} R(s) ds (+ e^{A k} [U]_n for dG)
    # after Galerkin orthogonality: A^m / m! times the residual's moment of degree m, m = q
    # (cG) or q + 1 (dG): q or q + 1 products with A per slab
    gx, gw = np.polynomial.legendre.leggauss(len(nodes) + 3)
    gx, gw = (gx + 1) / 2, gw / 2
    basis = np.array([[np.prod([(g - nodes[l]) / (nodes[j] - nodes[l])
                                for l in range(len(nodes)) if l != j]) for j in range(len(nodes))]
                      for g in gx])  # (G, q+1)
    dbasis = np.array([[sum(np.prod([(g - nodes[l]) / (nodes[j] - nodes[l])
                                     for l in range(len(nodes)) if l not in (j, i)])
                            / (nodes[j] - nodes[i]) for i in range(len(nodes)) if i != j)
                        for j in range(len(nodes))] for g in gx])
    start = np.array([np.prod([(0.0 - nodes[l]) / (nodes[j] - nodes[l])
                               for l in range(len(nodes)) if l != j]) for j in range(len(nodes))])
    is_dg = sol.method.family == "dG"
    mdeg = sol.method.q + (1 if is_dg else 0)
    fact = float(np.prod(np.arange(1, mdeg + 1)))
    dlead = np.empty((M, n))
    scale = atol_ratio + np.abs(flow(T, np.asarray(u0, dtype=float)))
    d = np.empty((M, n))
    r = np.empty((M, n))
    for m in range(M):
        d[m] = ends[m] - flow(ks[m], x)
        r[m] = wend @ vals[m] - ks[m] * (A @ ends[m] + b)
        Ug = basis @ vals[m]
        Rg = dbasis @ vals[m] / ks[m] - Ug @ A.T - b  # R at the Gauss points
        moment = ks[m] ** (mdeg + 1) * ((gw * (1 - gx) ** mdeg) @ Rg)
        if is_dg:
            moment += ks[m] ** mdeg * (start @ vals[m] - x)
        v = moment / fact
        for _ in range(mdeg):
            v = A @ v
        dlead[m] = v
        x = ends[m]
    err = np.max(np.abs(ends[-1] - flow(T, np.asarray(u0, dtype=float))) / scale)
    neutral = np.max(np.sum(np.abs(d), axis=0) / scale)
    q = sol.method.q
    lead = np.max(np.sum(np.abs(dlead), axis=0) / scale)
    slab_ratio = np.max(np.abs(dlead), axis=1) / np.maximum(np.max(np.abs(d), axis=1), 1e-300)
    lo, hi = np.percentile(slab_ratio, [10, 90])
    # d ~ c r^p: fit log|d| against log|r| over slabs (component of max |r|)
    dm = np.max(np.abs(d) / scale, axis=1)
    rm = np.max(np.abs(r) / scale, axis=1)
    ok = (dm > 0) & (rm > 0)
    p = np.polyfit(np.log(rm[ok]), np.log(dm[ok]), 1)[0] if ok.sum() > 2 else np.nan
    print(f"{name:9s} {method:6s} {tol:7.0e} slabs {M:6d}  err/tol {err / tol:9.3g}  "
          f"sum|d|/err {neutral / err:8.3g} sum|lead|/err {lead / err:8.3g} "
          f"lead/d 10-90% {lo:6.2g}-{hi:6.2g} "
          f"sum|r|/err {np.max(np.sum(np.abs(r), axis=0) / scale) / err:9.3g}"
          f"  d~c r^p: p {p:5.2f} (2q+1)/(q+1) {(2 * q + 1) / (q + 1):4.2f}", flush=True)


METHODS = ("cG(1)", "cG(2)", "cG(3)", "dG(1)", "dG(2)", "dG(3)")
TOLS = (1e-4, 1e-6)


def main():
    harm = np.array([[0.0, 1.0], [-1.0, 0.0]])
    chain = problems.mass_spring_chain(n=10, T=10.0)
    n = 10
    stiff = [int((m + 0.5) * (n + 1) / 2) for m in range(2)]
    kvec = np.where(np.isin(np.arange(n + 1), stiff), 1e4, 1.0)
    K = np.diag(-(kvec[:-1] + kvec[1:])) + np.diag(kvec[1:-1], 1) + np.diag(kvec[1:-1], -1)
    Ach = np.block([[np.zeros((n, n)), np.eye(n)], [K, np.zeros((n, n))]])
    hn = 20
    h = 1.0 / (hn + 1)
    L = (np.diag(-2.0 * np.ones(hn)) + np.diag(np.ones(hn - 1), 1) + np.diag(np.ones(hn - 1), -1)) / h**2
    src = np.zeros(hn)
    src[hn // 2] = 100.0 / h
    cases = [("harmonic", harm, np.zeros(2), np.array([0.0, 1.0]), 100.0, 1.0),
             ("chain10", Ach, np.zeros(2 * n), chain.ode.u0, 10.0, 1.0),
             ("heat20", L, src, np.zeros(hn), 0.1, 1.0)]
    for name, A, b, u0, T, ar in cases:
        for method in METHODS:
            for tol in TOLS:
                probe(name, A, b, u0, T, method, tol, ar)


if __name__ == "__main__":
    main()
