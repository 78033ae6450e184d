"""Nonlinear solvers for the stage equations of one mono-adaptive time slab.

The unknowns are the stage values X_s (s = 1..S) of the element polynomial, and the
discrete equations (see :mod:`dolfinode.methods.method`) read

    G(X)_s = X_s - x0 - k (b0_s f(x0, t) + sum_m A_sm f(X_m, t + tau_m k)) = 0.

* fixed-point iteration X <- X - G(X) converges when k ||A|| Lip(f) < 1 (non-stiff);
* simplified Newton solves (I - k A (x) J) dX = -G(X) with J = df/du(x0, t), split by the
  eigenstructure of A into N x N systems I - k lambda J, banded or sparse
  (:mod:`dolfinode.linalg.newton_matrix`) (stiff).

Increments are measured in the scaled max-norm |dX_i| w_i, w_i = 1 / (atol_i + rtol |X_i|),
X the current iterate (Newton) or the starting guess (fixed point, see there). An iteration
is converged when the estimated remaining error theta/(1 - theta) |dX| is below ``dtol``
(theta: observed contraction rate), or when |dX| stops decreasing at rounding level.
Both return the number of iterations, or -1 if the iteration diverged or did not converge.
"""
import math

from numba import njit, types

from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT, address
from dolfinode.counters import F_EVALUATIONS, FACTORIZATIONS, ITERATIONS
from dolfinode.linalg.banded import _u
from dolfinode.linalg.newton_matrix import lu_factor, lu_solve, shift

#: An iteration that stops contracting with scaled increments below this has reached rounding.
ROUNDING_LEVEL = 1e-10
#: The flags of :func:`newton`: give up as soon as the rate says the iteration cannot
#: converge in time; the residual formed in the transformed variables.
GIVE_UP = 1
TRANSFORMED = 2
#: The iteration errors of Newton's slabs together may take at most about this fraction of
#: the error the tolerance delivers at T (see newton_tolerance).
KAPPA = 0.1


@njit(cache=True, inline="always")
def scale_weights(X, atol, rtol, w):
    """w = 1 / (atol_i + rtol |X|) for flattened stage arrays (stage-major): the weights of the
    scaled norm, so that measuring an increment costs a product where a quotient costs ~4
    cycles."""
    N = atol.shape[0]
    for s in range(X.shape[0] // N):
        for i in range(N):
            w[s * N + i] = 1.0 / (atol[i] + rtol * abs(X[s * N + i]))


@njit(cache=True, inline="always")
def _weighted_max(result, dx, w):
    """max(result, |dx| w), a nan counting as inf."""
    v = abs(dx) * w
    # selects (minsd/maxsd), not branches: a branch on which entry is the largest is often
    # mispredicted (seed problem, cG(3): solve 4% faster); spelled out, as min/max leave
    # which operand a nan yields unsaid
    v = v if v <= math.inf else math.inf  # noqa: FURB136
    return v if v > result else result  # noqa: FURB136


@njit(cache=True, inline="always")
def weighted_norm(dx, w):
    """max_j |dx_j| w_j."""
    result = 0.0
    for j in range(dx.shape[0]):
        result = _weighted_max(result, dx[j], w[j])
    return result


@njit(cache=True, inline="always")
def newton_tolerance(dtol_k, floor, dtol, delivered, share, n):
    """Newton's stopping tolerance on the n-th slab (n = 0, 1, ...) of length k: a share of
    kappa x the error at T the tolerance delivers (kappa = KAPPA, ``delivered`` in units of
    the scaled norm's rtol), max(k/(T - t0), 1/(n + 1)) of it (``share`` = k/(T - t0)),
    between the rounding level ``floor`` and ``dtol``.

    RADAU5 stops its Newton iteration at kappa x its local tolerance (kappa ~ 0.03,
    Hairer-Wanner IV.8). Here the step tolerance is looser than the error asked at T (the
    nodes superconverge, :func:`dolfinode.adaptivity.step_tolerance`), and the slabs'
    iteration errors add up with one sign where the solution oscillates (VDPOLM, dG(3) at
    1e-9: 20 x the tolerance with the loop's dtol k/(T - t0) in step-tolerance units, 5 x
    the delivered error in all), so the slabs share a budget of the delivered error: over n
    slabs the shares sum to at most 2 + ln n. Steps graded over many decades (ROBER:
    k/(T - t0) < 1e-8) take the share 1/(n + 1) where k/(T - t0) says nothing. Without a
    delivered error (cG(q), fixed steps: ``delivered`` = 0) the loop's tolerance ``dtol_k``
    = max(dtol k/(T - t0), min(dtol, floor)) stands: cG(q) is not L-stable and keeps a
    stiff component's iteration error; the fixed-point iteration keeps dtol_k, as its
    iteration error drifts the energy of oscillations with one sign, where Newton's, exact on
    a linear system, leaves none.
    """
    if delivered == 0.0:
        return dtol_k
    return max(floor, min(dtol, KAPPA * delivered * max(share, 1.0 / (n + 1))))


@njit(cache=True, inline="always")
def _converged(d, d_prev, it, dtol, theta_floor):
    if d <= dtol:
        return True
    if it >= 1 and d_prev > 0.0:
        theta = max(d / d_prev, theta_floor)
        if theta < 1.0 and theta / (1.0 - theta) * d <= dtol:
            return True
        if it >= 2 and theta >= 0.5 and d <= ROUNDING_LEVEL:
            return True  # stagnation at rounding level
    return False


@njit(cache=True, inline="always")
def _hopeless(theta, d, dtol, left):
    """Whether an iteration contracting at theta from the increment d is predicted not to
    reach dtol in the ``left`` iterations it has: theta^left / (1 - theta) d > dtol (RADAU5's
    test, Hairer-Wanner IV.8). It would fail anyway, after spending them (HIRES, dG(3) at
    1e-6: two solves of 30 iterations at theta 0.7 on the slab at t = 284)."""
    return d > ROUNDING_LEVEL and theta ** left * d > (1.0 - theta) * dtol


@njit(cache=True, inline="always")
def stage_rhs(f, p, X, t, k, tau, F):
    """F[s] = f(X[s], t + tau_s k) for every stage; returns the number of f evaluations.

    f reads and writes the stages in place: copying its output (stored by f one entry at a
    time) with vector loads stalled on store forwarding, 5% of the seed problem's time.
    """
    S = tau.shape[0]
    N = X.shape[0] // S
    for s in range(S):
        f(address(X, s * N), t + tau[s] * k, address(p, 0), address(F, s * N))
    return S


@njit(cache=True, inline="always")
def _start4(c, f0, i):
    """c f0[i:i + 4], as four scalars (kept in registers)."""
    return c * f0[_u(i)], c * f0[_u(i + 1)], c * f0[_u(i + 2)], c * f0[_u(i + 3)]


@njit(cache=True, inline="always")
def _add4(sums, a, F, o):
    """sums + a F[o:o + 4]."""
    return (sums[0] + a * F[_u(o)], sums[1] + a * F[_u(o + 1)], sums[2] + a * F[_u(o + 2)],
            sums[3] + a * F[_u(o + 3)])


@njit(cache=True, inline="always")
def _store4(sums, out, i):
    for r in range(4):
        out[_u(i + r)] = sums[r]


@njit(cache=True, inline="always")
def _stage_sum(c, f0, F, A, s, out):
    """out = c f0 + sum_m A_sm F_m (one stage of the quadrature, c = b0_s; or with c = 0 one
    stage of a transformation F -> (A (x) I) F), in blocks of 8, 4, 3 or 2, and 1
    components whose sums stay in registers over m (stored once; the compiler packs them
    into vector registers); unsigned indices, see
    dolfinode.linalg.banded. Blocked, the sums cost a fraction of axpys over all components
    per m, in the same order of summation (the same results)."""
    N = f0.shape[0]
    S = A.shape[0]
    i = 0
    while i + 8 <= N:
        low = _start4(c, f0, i)
        high = _start4(c, f0, i + 4)
        for m in range(S):
            low = _add4(low, A[s, m], F, m * N + i)
            high = _add4(high, A[s, m], F, m * N + i + 4)
        _store4(low, out, i)
        _store4(high, out, i + 4)
        i += 8
    if i + 4 <= N:
        low = _start4(c, f0, i)
        for m in range(S):
            low = _add4(low, A[s, m], F, m * N + i)
        _store4(low, out, i)
        i += 4
    if i + 3 == N:
        # the last components side by side: one alone is a chain of dependent additions
        # over m (N = 2, 3: every component of the stage sums of a Newton iteration)
        a0 = c * f0[_u(i)]
        a1 = c * f0[_u(i + 1)]
        a2 = c * f0[_u(i + 2)]
        for m in range(S):
            a = A[s, m]
            a0 += a * F[_u(m * N + i)]
            a1 += a * F[_u(m * N + i + 1)]
            a2 += a * F[_u(m * N + i + 2)]
        out[_u(i)] = a0
        out[_u(i + 1)] = a1
        out[_u(i + 2)] = a2
        return
    if i + 2 <= N:
        a0 = c * f0[_u(i)]
        a1 = c * f0[_u(i + 1)]
        for m in range(S):
            a = A[s, m]
            a0 += a * F[_u(m * N + i)]
            a1 += a * F[_u(m * N + i + 1)]
        out[_u(i)] = a0
        out[_u(i + 1)] = a1
        i += 2
    if i < N:
        acc = c * f0[_u(i)]
        for m in range(S):
            acc += A[s, m] * F[_u(m * N + i)]
        out[_u(i)] = acc


@njit(cache=True, inline="always")
def _residual(x0, f0, X, F, A, b0, k, G):
    """G = X - x0 - k (b0 f0 + A F), stage-major."""
    N = x0.shape[0]
    for s in range(A.shape[0]):
        _stage_sum(b0[s], f0, F, A, s, G[s * N:])
        for i in range(N):
            e = _u(s * N + i)
            G[e] = X[e] - x0[_u(i)] - k * G[e]


# The iterations run without reference counting (NO_REFCOUNT), their helpers inlined.
@linked
@helper(**NO_REFCOUNT)
def fixed_point(f, p, x0, f0, t, k, A, b0, tau, atol, rtol, dtol, max_iter, X, F, G, w,
                counters):
    """Fixed-point iteration X <- x0 + k (b0 f0 + A F(X)) on the stages (in place in X); G[:N]
    and w are work space. Increments are scaled by the starting guess X (extrapolated from
    the last element), not by each iterate: one division per entry and slab, not per sweep."""
    S = A.shape[0]
    N = x0.shape[0]
    scale_weights(X, atol, rtol, w)
    d_prev = 0.0
    d_prev2 = 0.0
    for it in range(max_iter):
        counters[F_EVALUATIONS] += stage_rhs(f, p, X, t, k, tau, F)
        # stage by stage: the quadrature sum (_stage_sum), then X -= G and d = |G| w in one
        # pass, so that each stage's values are read once per sweep
        d = 0.0
        for s in range(S):
            _stage_sum(b0[s], f0, F, A, s, G)
            for i in range(N):
                e = _u(s * N + i)
                g = X[e] - x0[_u(i)] - k * G[_u(i)]
                X[e] -= g
                d = _weighted_max(d, g, w[e])
        counters[ITERATIONS] += 1
        if not math.isfinite(d):
            return -1
        if _converged(d, d_prev, it, dtol, 0.0):
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
def transformed_tables(A, b0, T_inverse, A_hat, b0_hat):
    """A_hat = T^{-1} A, b0_hat = T^{-1} b0: the tables of :func:`newton`'s transformed
    residual."""
    S = A.shape[0]
    for j in range(S):
        b0_hat[j] = 0.0
        for m in range(S):
            b0_hat[j] += T_inverse[j, m] * b0[m]
        for n in range(S):
            A_hat[j, n] = 0.0
            for m in range(S):
                A_hat[j, n] += T_inverse[j, m] * A[m, n]


@njit(cache=True, inline="always")
def near_step(k, k_factored, ratio):
    """Whether factors made on the step k_factored (0: none) serve the step k: the two within
    a factor ``ratio`` of each other."""
    return k_factored > 0.0 and k_factored <= ratio * k and k <= ratio * k_factored


@linked(returns=types.boolean, what="the stiff solver's factorization", seconds=2)
@helper(**NO_REFCOUNT)
def factor(ab, structure, ipiv, counters):
    """LU-factor a Newton matrix in place; returns True on success."""
    counters[FACTORIZATIONS] += 1
    return lu_factor(ab, structure, ipiv) == 0


@linked(returns=types.boolean, what="the stiff solver's stage factorization",
        seconds=2)
@helper(**NO_REFCOUNT)
def factor_stages(jb, k, eigenvalues, structure, ab_real, ab_complex, ipiv, counters):
    """LU factors of I - k lambda_j J (J in the storage ``jb`` of ``structure``, see
    :mod:`dolfinode.linalg.newton_matrix`) for the eigenvalues of the stage matrix: the real
    ones into ab_real[j], one per complex pair into ab_complex[c]. Returns True on success."""
    r = ab_real.shape[0]
    for j in range(r):
        shift(jb, k * eigenvalues[j].real, structure, ab_real[j])
        if not factor(ab_real[j], structure, ipiv[j], counters):
            return False
    for c in range(ab_complex.shape[0]):
        shift(jb, k * eigenvalues[r + c], structure, ab_complex[c])
        if not factor(ab_complex[c], structure, ipiv[r + c], counters):
            return False
    return True


@linked(returns=types.int64, what="the stiff solver", seconds=4)
@helper(**NO_REFCOUNT)
def newton(f, p, x0, f0, t, k, A, b0, tau, T, T_inverse, atol, rtol, dtol, max_iter, theta_max,
           flags, X, F, G, Z, ab_real, ab_complex, structure, ipiv, z_real, z_complex, w,
           counters, rate):
    """Simplified Newton iteration on the stages, (I - k A (x) J) dX = -G(X), with the
    factors of :func:`factor_stages`: with A = T B T^{-1} (``T``, ``T_inverse``) the system is
    (I - k B (x) J) Z = -(T^{-1} (x) I) G, dX = (T (x) I) Z, and B's blocks decouple it into
    one N x N solve per real eigenvalue and one complex one per pair (RADAU5's
    transformation): S N x S N with bandwidth ~S b becomes ~S/2 N x N with bandwidth b.

    ``flags``: GIVE_UP and TRANSFORMED, or'ed (one argument: each argument more of this
    linked routine cost about 0.3 us a call, doc/design/newton.md).

    It fails when an increment shrinks by less than ``theta_max`` (1: when it grows), and
    with GIVE_UP as soon as it cannot reach dtol in max_iter iterations at its rate
    (:func:`_hopeless`; dG(q): cG(q)'s slabs with an undamped stiff deviation converge
    late, and its failures count towards the loop's stop, mono.UNDAMPED_FAILURES); the
    largest contraction rate theta = |dX_(m+1)| / |dX_m| seen goes to ``rate[0]`` (0 after
    one iteration), which tells the caller how well J and the factors still fit. It stops
    when theta/(1 - theta) |dX| <= ``dtol`` (:func:`newton_tolerance`), theta at least the
    rate ``rate[0]`` of the solve before (RADAU5 carries its rate likewise): the first ratio
    |dX_1| / |dX_0| mostly measures the start's error, which the first iteration removes at
    once (HIRES: 0.01 where the rest contracts at 0.2-0.5).

    TRANSFORMED (dG(q)): A and b0 are T^{-1} A and T^{-1} b0 (:func:`transformed_tables`)
    and the residual is formed in the transformed variables, as RADAU5 forms it,

        (T^{-1} (x) I) G = V - k (T^{-1} A (x) I) F,
        V = (T^{-1} (x) I)(X - 1 (x) x0) - k (T^{-1} b0) (x) f0,

    V made once and updated by V += Z: two stage sums an iteration, not three (5-9 % of
    dG(3)'s and dG(5)'s solve). It converges to the equations with T^{-1} A rounded,
    coefficients off by about cond(T) x eps on every slab: far below a dissipative method's
    error, but a drift of cG(3)'s energy on a long oscillation (5e-12 over 10^4 periods
    against 1e-13), so cG(q) forms G as it is. V lives in the second half of Z (length
    2 S N), not in an argument."""
    position = structure[0]
    S = A.shape[0]
    N = x0.shape[0]
    r = ab_real.shape[0]
    d_prev = 0.0
    # the first ratio |dX_1| / |dX_0| is mostly the predictor's error, removed at once, and
    # underestimates the rate at which the rest contracts: the last solve's rate bounds it
    # (not a diverged one's)
    carried = rate[0] if rate[0] < 1.0 else 0.0
    rate[0] = 0.0
    give_up = (flags & GIVE_UP) != 0
    transformed = (flags & TRANSFORMED) != 0
    V = Z[S * N:]
    if transformed:
        for s in range(S):
            for i in range(N):
                G[s * N + i] = X[s * N + i] - x0[i]
        for j in range(S):
            _stage_sum(-k * b0[j], f0, G, T_inverse, j, V[j * N:])
    for it in range(max_iter):
        counters[F_EVALUATIONS] += stage_rhs(f, p, X, t, k, tau, F)
        if transformed:  # Z = V - k (T^{-1} A (x) I) F
            for j in range(S):
                _stage_sum(0.0, x0, F, A, j, Z[j * N:])
                for i in range(N):
                    Z[j * N + i] = V[j * N + i] - k * Z[j * N + i]
        else:
            _residual(x0, f0, X, F, A, b0, k, G)
            for j in range(S):  # Z = (T^{-1} (x) I) G
                _stage_sum(0.0, x0, G, T_inverse, j, Z[j * N:])
        # Z_j <- (I - k lambda_j J)^{-1} (-Z_j), in the matrices' ordering; a complex pair's two
        # real blocks are the real and imaginary parts of one complex vector
        for j in range(r):
            for i in range(N):
                z_real[position[i]] = -Z[j * N + i]
            lu_solve(ab_real[j], structure, ipiv[j], z_real)
            for i in range(N):
                Z[j * N + i] = z_real[position[i]]
        for c in range(ab_complex.shape[0]):
            re = (r + 2 * c) * N
            for i in range(N):
                z_complex[position[i]] = complex(-Z[re + i], -Z[re + N + i])
            lu_solve(ab_complex[c], structure, ipiv[r + c], z_complex)
            for i in range(N):
                Z[re + i] = z_complex[position[i]].real
                Z[re + N + i] = z_complex[position[i]].imag
        for s in range(S):  # dX = (T (x) I) Z, into G
            _stage_sum(0.0, x0, Z, T, s, G[s * N:])
        for e in range(S * N):
            X[e] += G[e]
        if transformed:
            for e in range(S * N):
                V[e] += Z[e]
        counters[ITERATIONS] += 1
        scale_weights(X, atol, rtol, w)
        d = weighted_norm(G, w)
        if not math.isfinite(d):
            return -1
        if it >= 1 and d > ROUNDING_LEVEL:  # not a stagnation at rounding level
            rate[0] = max(rate[0], d / d_prev)
        if _converged(d, d_prev, it, dtol, carried):
            return it + 1
        if it >= 1 and (d >= theta_max * d_prev
                        or give_up and _hopeless(d / d_prev, d, dtol, max_iter - 1 - it)):
            return -1
        d_prev = d
    return -1
