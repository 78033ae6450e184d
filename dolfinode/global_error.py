"""An a posteriori estimate of the error at T of a mono-adaptive cG(q)/dG(q) solution.

The error at T is the sum of the slabs' local nodal errors d_n, each carried to T by the
linearised flow. Here both are computed with the method's own discrete operators, which damp
the stiff modes as the method does:

    e_{n+1} = R_n e_n + d_n,   e_0 = 0,   estimate = e_M,

- R_n: the slab's linearised solution map, the method applied to e' = J_n e on I_n (for linear
  constant coefficients cG(q) is the q-stage Gauss collocation, the (q, q) Pade function of
  k J, and dG(q) the (q + 1)-stage Radau IIA collocation, the (q, q + 1) Pade function);
- d_n: the local nodal error, the solution at t_{n+1} of the error equation
  e' = J_n e + R(t), e(t_n) = [U]_n, with the residual R = U' - f(t, U) of the slab
  polynomial and the jump [U]_n (zero for cG), solved by the (q + 2)-stage Radau IIA
  collocation: exact on the degree-2q + 2 moments that Galerkin orthogonality leaves, and
  L-stable, so that it stays bounded (d ~ -J^{-1} R) where k |lambda| >> 1.

J_n = df/du at the slab's end. The estimate is signed: errors that cancel over periods
cancel in it, and errors that grow (a period drifting with the energy) grow in it.
"""
import numpy as np
import sympy as sp
from numpy.polynomial import legendre

from dolfinode.ode import t as time_symbol


def collocation_tableau(nodes):
    """Butcher tableau (a, b) of the collocation method on ``nodes`` in [0, 1]:
    a_ij = int_0^{c_i} l_j, b_j = int_0^1 l_j with l_j the Lagrange basis on the nodes."""
    nodes = np.asarray(nodes, dtype=float)
    s = len(nodes)
    V = np.vander(nodes, increasing=True)  # V[i, p] = c_i^p
    # l_j(x) = sum_p C[p, j] x^p with C = V^{-1}
    C = np.linalg.inv(V)
    powers = np.arange(1, s + 1)
    a = (nodes[:, None] ** powers[None, :] / powers[None, :]) @ C
    b = (1.0 / powers) @ C
    return a, b


def gauss_nodes(s):
    """The s Gauss-Legendre points on [0, 1]."""
    return (legendre.leggauss(s)[0] + 1) / 2


def radau_nodes(s):
    """The s right Radau points on [0, 1] (the last is 1): roots of P_s - P_{s-1} on [-1, 1]."""
    c = np.zeros(s + 1)
    c[s], c[s - 1] = 1.0, -1.0
    return np.sort((legendre.legroots(c).real + 1) / 2)


def lagrange_matrices(nodes, x):
    """(B, D): B[i, j] = l_j(x_i), D[i, j] = l_j'(x_i) for the Lagrange basis on ``nodes``."""
    nodes = np.asarray(nodes, dtype=float)
    C = np.linalg.inv(np.vander(nodes, increasing=True))
    p = np.arange(len(nodes))
    X = np.asarray(x, dtype=float)[:, None]
    B = (X ** p) @ C
    D = (p * X ** np.maximum(p - 1, 0)) @ C
    return B, D


def _lambdified(ode):
    """f(t, U) and J(t, U) for U of shape (P, N), vectorised over the P points."""
    subs = dict(ode.params) if ode.params else {}
    rhs = [sp.sympify(e).subs(subs) for e in ode.rhs]
    states = list(ode.states)
    jac = sp.Matrix(rhs).jacobian(states)
    N = len(states)
    f_l = sp.lambdify([time_symbol, *states], rhs, "numpy")
    J_l = sp.lambdify([time_symbol, *states], list(jac), "numpy")
    constant = not (jac.free_symbols & (set(states) | {time_symbol}))

    def f(t, U):
        out = f_l(t, *U.T)
        return np.stack([np.broadcast_to(np.asarray(v, dtype=float), t.shape) for v in out], -1)

    def J(t, U):
        out = J_l(t, *U.T)
        J = np.stack([np.broadcast_to(np.asarray(v, dtype=float), t.shape) for v in out], -1)
        return J.reshape(len(t), N, N)

    return f, J, constant


def _residual(sol, f, nodes_at):
    """R = U' - f(t, U) of each slab at the relative points ``nodes_at``: (M, len, N); and
    the jumps U(t_n^+) - U(t_n^-): (M, N)."""
    nodes = np.asarray(sol.method.nodes, dtype=float)
    vals, k, t0 = sol.values, sol.k, sol.t_start
    M, _, N = vals.shape
    B, D = lagrange_matrices(nodes, nodes_at)
    U = np.einsum("ij,mjn->min", B, vals)
    dU = np.einsum("ij,mjn->min", D, vals) / k[:, None, None]
    t = (t0[:, None] + nodes_at[None, :] * k[:, None]).ravel()
    R = dU - f(t, U.reshape(-1, N)).reshape(M, len(nodes_at), N)
    start = lagrange_matrices(nodes, [0.0])[0][0] @ vals  # (M, N)
    before = np.concatenate([np.asarray(sol.ode.u0, dtype=float)[None, :], vals[:-1, -1, :]])
    return R, start - before


def _propagation_nodes(method):
    return gauss_nodes(method.q) if method.family == "cG" else radau_nodes(method.q + 1)


def _modal(sol, J0, R, jump, a_err, a_prop, b_prop):
    """The recursion in the eigenbasis of a constant J0: every slab's operators are scalar
    per mode, so that all slabs are computed at once."""
    lam, V = np.linalg.eig(J0)
    Vi = np.linalg.inv(V)
    k = sol.k
    z = k[:, None] * lam[None, :]  # (M, N)
    Rm = np.einsum("ij,msj->msi", Vi, R.astype(complex))  # (M, s, N)
    jm = jump @ Vi.T
    s = len(a_err)
    # stage equations per mode: (I - z a) E = 1 e0 + k a R
    lhs = np.eye(s)[None, None] - z[:, :, None, None] * a_err[None, None]
    rhs = jm[:, :, None] + k[:, None, None] * np.einsum("ij,mjn->mni", a_err, Rm)
    d = np.linalg.solve(lhs, rhs[..., None])[..., -1, 0]  # stiffly accurate: the last stage
    sp_ = len(b_prop)
    lhs = np.eye(sp_)[None, None] - z[:, :, None, None] * a_prop[None, None]
    Y = np.linalg.solve(lhs, np.ones((1, 1, sp_, 1)))[..., 0]
    Rn = 1 + z * (Y @ b_prop)  # the stability function R(z) per slab and mode
    # e_M = sum_n (prod_{m > n} R_m) d_n
    after = np.cumprod(Rn[::-1], axis=0)[::-1]
    after = np.concatenate([after[1:], np.ones((1, len(lam)))])
    return (V @ np.sum(after * d, axis=0)).real


def _stage_jacobians(sol, J, nodes, part):
    """J(t, U) at the relative points ``nodes`` of the slabs ``part``: (M, len, N, N)."""
    B = lagrange_matrices(sol.method.nodes, nodes)[0]
    U = np.einsum("ij,mjn->min", B, sol.values[part])
    M, s, N = U.shape
    t = (sol.t_start[part, None] + nodes[None, :] * sol.k[part, None]).ravel()
    return J(t, U.reshape(-1, N)).reshape(M, s, N, N)


def _dense(sol, J, R, jump, c_err, a_err, c_prop, a_prop, b_prop, chunk=1024):
    """The recursion with J evaluated at each slab's stage points (dense, for small systems):
    the stage systems (I - k a (x) J_j) of the collocation methods on the linearised problem."""
    M, s, N = R.shape
    k = sol.k
    d = np.empty((M, N))
    Rmap = np.empty((M, N, N))
    I_N = np.eye(N)
    p = len(b_prop)
    for lo in range(0, M, chunk):
        hi = min(lo + chunk, M)
        part = slice(lo, hi)
        kk = k[part, None, None]
        Je = _stage_jacobians(sol, J, c_err, part)
        lhs = np.eye(s * N)[None] - kk * np.einsum("ij,mjab->miajb", a_err, Je).reshape(-1, s * N, s * N)
        rhs = (np.tile(jump[part], (1, s))
               + k[part, None] * np.einsum("ij,mjn->min", a_err, R[part]).reshape(-1, s * N))
        d[part] = np.linalg.solve(lhs, rhs[..., None])[:, -N:, 0]
        Jp = _stage_jacobians(sol, J, c_prop, part)
        lhs = np.eye(p * N)[None] - kk * np.einsum("ij,mjab->miajb", a_prop, Jp).reshape(-1, p * N, p * N)
        Y = np.linalg.solve(lhs, np.tile(I_N, (p, 1))[None].repeat(hi - lo, 0)).reshape(-1, p, N, N)
        Rmap[part] = I_N + kk * np.einsum("j,mjab,mjbc->mac", b_prop, Jp, Y)
    e = np.zeros(N)
    for n in range(M):
        e = Rmap[n] @ e + d[n]
    return e


def estimate(sol):
    """The signed estimate e(T) ~ U(T) - u(T), shape (N,), of a mono-adaptive cG(q)/dG(q)
    solution (see the module docstring)."""
    method = sol.method
    f, J, constant = _lambdified(sol.ode)
    s = method.q + 2
    c_err = radau_nodes(s)
    a_err, _ = collocation_tableau(c_err)
    c_prop = _propagation_nodes(method)
    a_prop, b_prop = collocation_tableau(c_prop)
    R, jump = _residual(sol, f, c_err)
    if constant:
        J0 = J(sol.t_start[:1], sol.values[:1, -1, :])[0]
        return _modal(sol, J0, R, jump, a_err, a_prop, b_prop)
    return _dense(sol, J, R, jump, c_err, a_err, c_prop, a_prop, b_prop)
