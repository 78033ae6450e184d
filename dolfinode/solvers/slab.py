"""Nonlinear solvers for the stage equations of one mono-adaptive time slab.

The unknowns are the stage values X_s (s = 1..S) of the element polynomial, and the
discrete equations (see :mod:`dolfinode.methods.method`) read

    G(X)_s = X_s - x0 - k (b0_s f(x0, t) + sum_m A_sm f(X_m, t + tau_m k)) = 0.

* fixed-point iteration X <- X - G(X) converges when k ||A|| Lip(f) < 1 (non-stiff);
* simplified Newton solves (I - k A (x) J) dX = -G(X) with J = df/du(x0, t), assembled in
  band storage in the component ordering chosen by ``bandwidth_ordering`` (stiff).

Increments are measured in the scaled max-norm |dX_i| / (atol_i + rtol |X_i|). An iteration
is converged when the estimated remaining error theta/(1 - theta) |dX| is below ``dtol``
(theta: observed contraction rate), or when |dX| stops decreasing at rounding level.
Both return the number of iterations, or -1 if the iteration diverged or did not converge.
"""
import math

from numba import njit

from dolfinode.linalg.banded import band_lu, band_solve
from dolfinode.timeslab import F_EVALUATIONS, FACTORIZATIONS, ITERATIONS

#: An iteration that stops contracting with scaled increments below this has reached rounding.
ROUNDING_LEVEL = 1e-10


@njit(cache=True)
def scaled_norm(dx, x, atol, rtol):
    """max_i |dx_i| / (atol_i + rtol |x_i|) for flattened stage arrays (stage-major)."""
    n = atol.shape[0]
    result = 0.0
    for idx in range(dx.shape[0]):
        i = idx % n
        v = abs(dx[idx]) / (atol[i] + rtol * abs(x[idx]))
        if not v <= result:  # also catches nan
            result = v if math.isfinite(v) else math.inf
    return result


@njit(cache=True)
def _converged(d, d_prev, it, dtol):
    if d <= dtol:
        return True
    if it >= 1 and d_prev > 0.0:
        theta = d / d_prev
        if theta < 1.0 and theta / (1.0 - theta) * d <= dtol:
            return True
        if it >= 2 and theta >= 0.5 and d <= ROUNDING_LEVEL:
            return True  # stagnation at rounding level
    return False


@njit(cache=True)
def stage_rhs(f, p, X, t, k, tau, F, tmp_in, tmp_out):
    """F[s] = f(X[s], t + tau_s k) for every stage; returns the number of f evaluations."""
    S = tau.shape[0]
    N = tmp_in.shape[0]
    for s in range(S):
        for i in range(N):
            tmp_in[i] = X[s * N + i]
        f(tmp_in.ctypes, t + tau[s] * k, p.ctypes, tmp_out.ctypes)
        for i in range(N):
            F[s * N + i] = tmp_out[i]
    return S


@njit(cache=True)
def _residual(x0, f0, X, F, A, b0, k, G):
    """G = X - x0 - k (b0 f0 + A F), stage-major."""
    S = A.shape[0]
    N = x0.shape[0]
    for s in range(S):
        for i in range(N):
            acc = b0[s] * f0[i]
            for m in range(S):
                acc += A[s, m] * F[m * N + i]
            G[s * N + i] = X[s * N + i] - x0[i] - k * acc


@njit(cache=True)
def fixed_point(f, p, x0, f0, t, k, A, b0, tau, atol, rtol, dtol, max_iter, X, F, G,
                tmp_in, tmp_out, counters):
    """Fixed-point iteration X <- x0 + k (b0 f0 + A F(X)) on the stages (in place in X)."""
    d_prev = 0.0
    d_prev2 = 0.0
    for it in range(max_iter):
        counters[F_EVALUATIONS] += stage_rhs(f, p, X, t, k, tau, F, tmp_in, tmp_out)
        _residual(x0, f0, X, F, A, b0, k, G)
        for idx in range(X.shape[0]):
            X[idx] -= G[idx]
        counters[ITERATIONS] += 1
        d = scaled_norm(G, X, atol, rtol)
        if not math.isfinite(d):
            return -1
        if _converged(d, d_prev, it, dtol):
            return it + 1
        # Diverging (the slab is stiff for fixed-point iteration) when two iterations did not
        # shrink the increment: k A (x) J is far from normal for q >= 3, and one increment may
        # grow on a converging iteration (chain, cG(5): 0.25, 1.6e-4, 3.2e-4, ...).
        if it >= 2 and d >= d_prev2:
            return -1
        d_prev2 = d_prev
        d_prev = d
    return -1


@njit(cache=True)
def assemble_newton_matrix(jdata, indptr, indices, position, A, k, kl, ku, ab):
    """Band storage of I - k A (x) J, unknown (component i, stage s) at row position[i] S + s."""
    S = A.shape[0]
    n = ab.shape[0]
    N = position.shape[0]
    kv = kl + ku
    ab[:, :] = 0.0
    for i in range(N):
        ri = position[i] * S
        for nz in range(indptr[i], indptr[i + 1]):
            cj = position[indices[nz]] * S
            value = -k * jdata[nz]
            for s in range(S):
                for m in range(S):
                    ab[cj + m, kv + ri + s - cj - m] += value * A[s, m]
    for r in range(n):
        ab[r, kv] += 1.0


@njit(cache=True)
def newton(f, p, x0, f0, t, k, A, b0, tau, atol, rtol, dtol, max_iter, X, F, G,
           tmp_in, tmp_out, ab, kl, ku, ipiv, position, rhs_perm, counters):
    """Simplified Newton iteration on the stages with the factored matrix in ``ab``."""
    S = A.shape[0]
    N = x0.shape[0]
    d_prev = 0.0
    for it in range(max_iter):
        counters[F_EVALUATIONS] += stage_rhs(f, p, X, t, k, tau, F, tmp_in, tmp_out)
        _residual(x0, f0, X, F, A, b0, k, G)
        for s in range(S):
            for i in range(N):
                rhs_perm[position[i] * S + s] = -G[s * N + i]
        band_solve(ab, kl, ku, ipiv, rhs_perm)
        for s in range(S):
            for i in range(N):
                G[s * N + i] = rhs_perm[position[i] * S + s]
                X[s * N + i] += G[s * N + i]
        counters[ITERATIONS] += 1
        d = scaled_norm(G, X, atol, rtol)
        if not math.isfinite(d):
            return -1
        if _converged(d, d_prev, it, dtol):
            return it + 1
        if it >= 1 and d >= d_prev:
            return -1
        d_prev = d
    return -1


@njit(cache=True)
def factor(ab, kl, ku, ipiv, counters):
    """LU-factor the Newton matrix; returns True on success."""
    counters[FACTORIZATIONS] += 1
    return band_lu(ab, kl, ku, ipiv) == 0
