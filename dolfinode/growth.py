"""Growing modes that a step spans: where the step control cannot see the error.

On a step of length k from U_n, a mode of the Jacobian J = df/du with eigenvalue lambda,
Re lambda > 0, grows by exp(z), z = k lambda, in the exact flow, and by the method's
stability function R(z) in the discrete one (:func:`dolfinode.methods.method.
stability_function`): |R(z)| <= 1 for large z (L-stable dG(q) damps it to 0). Its amplitude
at U_n is the distance to the equilibrium along the mode, f(U_n) ~ J (U_n - U*) hence

    a = |w^T f(U_n)| / |lambda|,   w the mode's left eigenvector (w^T v = 1),

and the step's error in that mode is a |exp(z) - R(z)| v. The step control measures the
residual, which stays small while a sits below the tolerance: u' = 50 (u - 1) from
u0 = 1 + 1e-6 took one step to T = 1 and returned u = 1 where u(1) = 5e15 (dG(2), mdG(1),
cG(1), dG(0), unwarned), and u' = 1e100 u returned u(T) = 0. A run is warned where a step
with Re z > SPANNED misses more than MISSED x the tolerance (atol_i + rtol |U_i|) in a
mode. For a multi-adaptive run z is an eigenvalue of K J, K = diag(k_i) the components'
steps (k J for a shared step). The steps' Gershgorin bound max_i k_i (J_ii + sum_j |J_ij|)
of Re z selects the candidates; of a system of at most CERTIFIED components each is then
certified (no eigenvalue with Re z > SPANNED: the spectral abscissa of the comparison
matrix of K J, or of W K J V in the eigenbasis V of a step decomposed before, kept per
compiled system for the next check, is below SPANNED) or decomposed, which on stiff
decaying runs leaves none (the plain bound selected every stiff step: off-diagonal
couplings). The bound plus log max_i |k_i f_i| / (atol_i + rtol |U_i|) of log(a exp(z))
ranks those left (at most MAX_CANDIDATES), so that a run without growing modes pays one
Jacobian per step and few decompositions.
"""
from itertools import pairwise

import numpy as np
from numba import njit
from scipy.linalg import lapack

from dolfinode.compile.jit import helper
from dolfinode.compile.signatures import address, call_rhs_rows, rhs_kernel
from dolfinode.methods.method import stability_function

#: A step spans a mode where Re z > SPANNED (the mode grows e-fold within the step).
SPANNED = 1.0
#: The step's error in a spanned mode is reported above MISSED x the tolerance (an error of
#: atol becoming 10 atol, as :data:`dolfinode.solve.LOST_GROWTH`).
MISSED = 10.0
#: At most MAX_CANDIDATES steps (the largest bounds of log(a exp(z))) get a dense
#: eigen-decomposition (on VDPOL every step is a candidate, J_21 ~ 1e6: the decompositions of
#: all 452 cost more than the solve), fewer where their matrices would hold more than
#: DENSE_ENTRIES numbers; systems of more than MAX_DENSE components are not checked.
MAX_CANDIDATES, DENSE_ENTRIES, MAX_DENSE = 8, 2**21, 512
#: Double precision's machine epsilon (a module constant: numba reads it compiled in).
EPS = np.finfo(float).eps
#: Steps whose bounds are computed at once (the Jacobian's values of a chunk are held).
CHUNK = 4096
#: Systems of at most CERTIFIED components have each step the Gershgorin bound selects
#: certified or decomposed (:func:`_growing`: its dense products cost N^3 a step).
CERTIFIED = 32


def spanned_growth(sol, compiled, m, atol, rtol):
    """The step of ``sol`` (by the method ``m``, tolerances ``atol``, ``rtol``) that misses
    the most of a growing mode, as (t, z, ratio, i, k): its start time, z = k lambda, the
    error over the tolerance in the mode (log10: it may be past double precision), the
    component i the mode moves most and its step k; None where no step misses more than
    MISSED x the tolerance (or ``sol`` has no history, or more than MAX_DENSE components)."""
    N = compiled.N
    if not sol.dense or N > MAX_DENSE:
        return None
    most = max(1, min(MAX_CANDIDATES, DENSE_ENTRIES // N**2))
    times, steps, states = _steps(sol)
    bounds, chosen = np.empty(0), np.empty(0, dtype=np.int64)
    for start in range(0, len(times), CHUNK):
        rows = slice(start, start + CHUNK)
        U, K = states(rows), steps(rows)
        values = _jacobian_values(compiled, U, times[rows])
        bound = _gershgorin(values, compiled.indptr, compiled.indices, K)
        keep = np.flatnonzero(bound > SPANNED)
        if N <= CERTIFIED:
            keep = _growing(values, compiled.indptr, compiled.indices, K, keep,
                            compiled.growth_basis)
        if not keep.size:
            continue
        # ranked by log(a exp(z)) <= bound + log |K f|_scaled: a spanned mode's error
        f = np.empty((keep.size, N))
        call_rhs_rows(compiled.rhs.address, np.ascontiguousarray(U[keep]),
                      np.ascontiguousarray(times[rows][keep]), compiled.p, f)
        with np.errstate(divide="ignore"):
            size = np.log(np.max(np.abs(K[keep] * f) / (atol + rtol * np.abs(U[keep])), axis=1))
        bounds = np.concatenate([bounds, bound[keep] + size])
        chosen = np.concatenate([chosen, keep + start])
        if chosen.size > most:
            top = np.argsort(bounds)[-most:]
            bounds, chosen = bounds[top], chosen[top]
    chosen = chosen[np.isfinite(bounds) | (bounds > 0)]  # (f = 0: nothing to grow)
    if not chosen.size:
        return None
    U = np.concatenate([states(slice(c, c + 1)) for c in chosen.tolist()])
    K = np.concatenate([steps(slice(c, c + 1)) for c in chosen.tolist()])
    J = np.zeros((chosen.size, N, N))
    rows = np.repeat(np.arange(N), np.diff(compiled.indptr))
    J[:, rows, compiled.indices] = _jacobian_values(compiled, U, times[chosen])
    f = np.empty((chosen.size, N))
    call_rhs_rows(compiled.rhs.address, U, np.ascontiguousarray(times[chosen]), compiled.p, f)
    found = _missed(K[:, :, None] * J, K * f, U, atol, rtol, *stability_function(m))
    if found is None:
        return None
    c, z, ratio, i = found
    return float(times[chosen[c]]), z, ratio, i, float(K[c, i])


def _jacobian_values(compiled, U, times):
    """The Jacobian's nonzero values (P, nnz) at the states U (P, N) and ``times``."""
    data = np.empty((len(times), max(compiled.nnz, 1)))
    call_rhs_rows(compiled.jacobian.address, np.ascontiguousarray(U),
                  np.ascontiguousarray(times), compiled.p, data)
    return data[:, :compiled.nnz]


def _steps(sol):
    """(times, steps, states): the start of every step, and functions of a slice of the
    steps that give, per step, the step of each component there ((P, N); the shared step of
    a cG(q)/dG(q) run) and U there ((P, N): a shared step's from the previous step's end,
    which it starts from)."""
    N = sol.ode.N
    if not sol.multi:
        t_start, k = sol.time_steps()
        ends = sol.values[:, -1, :]

        def states(rows):
            first, last, _ = rows.indices(len(t_start))
            before = ends[max(first - 1, 0):max(last - 1, 0)]
            return np.concatenate([sol.ode.u0[None, :], before]) if first == 0 else before

        return t_start, lambda rows: np.repeat(k[rows, None], N, axis=1), states
    partitions = _partitions(sol)
    times = np.unique(np.concatenate([start for start, _ in partitions]))
    steps = np.empty((times.size, N))
    for i, (start, end) in enumerate(partitions):
        at = np.clip(np.searchsorted(start, times, side="right") - 1, 0, start.size - 1)
        steps[:, i] = (end - start)[at]
    # (U's polynomials, as the nodal values above: the dense value reads f, and its kernels
    # would compile with the first multi-adaptive solve, which does not need them)
    return times, lambda rows: steps[rows], lambda rows: sol._values(times[rows], dense=False).T


def _partitions(sol):
    """Per component of a multi-adaptive ``sol``, its elements' (start, end), time-sorted;
    of a mixed history (its own elements and shared slabs) without joining them, which
    would copy every value (:class:`dolfinode.solution.MixedSolution`)."""
    parts = sol.__dict__.get("_parts")
    if parts is None:
        ptr, t_start, t_end, _ = sol.elements()
        return [(t_start[a:b], t_end[a:b]) for a, b in pairwise(ptr)]
    ptr, t_start, t_end, _, s_start, s_end, _ = parts
    partitions = []
    for a, b in pairwise(ptr):
        start = np.concatenate([t_start[a:b], s_start])
        order = np.argsort(start, kind="stable")
        partitions.append((start[order], np.concatenate([t_end[a:b], s_end])[order]))
    return partitions


@helper()
def may_span(jacobian, indptr, indices, p, u0, starts, lengths, X, n):
    """Whether a step of the first ``n`` elements of a cG(q)/dG(q) history (``starts``,
    ``lengths``, ``X`` (capacity, q + 1, N): nodal values; from ``u0``) may span a growing
    mode: where Gershgorin's bound of Re z (:func:`spanned_growth`'s first test) passes
    SPANNED at a step's start, J from the kernel at the address ``jacobian``. Compiled into
    a prepared call (:mod:`dolfinode.timeslab.prepared`), which checks a run of one step by
    it before :func:`spanned_growth` (whose Python costs several prepared calls)."""
    data = np.empty(max(indices.size, 1))
    kernel = rhs_kernel(jacobian)
    N, q = u0.size, X.shape[1] - 1
    for step in range(n):
        # U at the step's start: u0, else the previous step's end X[step - 1, q]
        u = address(u0, 0) if step == 0 else address(X, ((step - 1) * (q + 1) + q) * N)
        kernel(u, starts[step], address(p, 0), address(data, 0))
        for i in range(N):
            if lengths[step] * _row_bound(data, indptr, indices, i) > SPANNED:
                return True
    return False


@njit(cache=True)
def _gershgorin(data, indptr, indices, steps):
    """Per step p, max_i k_pi (J_ii + sum_{j != i} |J_ij|) from J's nonzero values ``data``
    (P, nnz, CSR order): a bound of Re z over the eigenvalues z of K J."""
    out = np.zeros(data.shape[0])
    for p in range(data.shape[0]):
        best = -np.inf
        for i in range(indptr.size - 1):
            best = max(best, steps[p, i] * _row_bound(data[p], indptr, indices, i))
        out[p] = best
    return out


@njit(cache=True)
def _row_bound(values, indptr, indices, i):
    """J_ii + sum_{j != i} |J_ij| of row i, from J's nonzero ``values`` (CSR order)."""
    row = 0.0
    for m in range(indptr[i], indptr[i + 1]):
        row += values[m] if indices[m] == i else abs(values[m])
    return row


def _growing(data, indptr, indices, steps, candidates, kept):
    """The ``candidates`` (step indices) whose Z = K J (J's nonzero values ``data``, (P, nnz),
    CSR order; ``steps`` K, (P, N)) has an eigenvalue with Re z > SPANNED. Each is certified
    without (:func:`_certified`): by the comparison matrix of Z, or of B = W Z V, V the
    eigenvectors of the last step decomposed (W = V^-1: B is similar to Z, and near
    diagonal while J changes little), else it is decomposed (:func:`_basis`). ``kept``:
    [the basis (V, W) of the last decomposition of an earlier check of this system, or
    None], where this one starts, and which it updates: a second solve of a system (other
    values, parameters) mostly decomposes nothing. Any invertible V certifies only what
    has no growing mode (B is similar to Z whatever V is)."""
    Z = np.empty((indptr.size - 1,) * 2)  # (the Z of the step _certified stopped at)
    basis, growing, at = kept[0] or NO_BASIS, [], 0  # (no basis: Z's comparison matrix)
    while True:
        at += _certified(data, indptr, indices, steps, candidates[at:], *basis, Z)
        if at == candidates.size:
            return np.array(growing, dtype=np.int64)
        grows, basis = _basis(Z)
        if basis is not NO_BASIS:
            kept[0] = basis
        if grows:
            growing.append(candidates[at])
        at += 1


#: V, W of :func:`_certified` where there is no basis.
NO_BASIS = (np.empty((0, 0), dtype=np.complex128),) * 2


def _basis(Z):
    """(whether Z has an eigenvalue with Re z > SPANNED, (V, W)): its eigenvectors V and
    W = V^-1 (up to rounding: :func:`_certified` bounds it); NO_BASIS where Z is not
    finite (left to the ranking: Gershgorin's bound selected it) or defective. LAPACK's
    routines directly: numpy's eig costs 16 us on 3 x 3 (its checks), dgeev 2."""
    if not np.isfinite(Z).all():
        return True, NO_BASIS
    real, imaginary, _, vectors, failed = lapack.dgeev(Z, compute_vl=0)
    if failed:
        return True, NO_BASIS
    grows = not (real <= SPANNED).all()
    # a complex pair's vectors are columns j, j + 1 (Im z_j > 0): v = VR_j +- i VR_j+1
    V, pair = vectors.astype(np.complex128), np.flatnonzero(imaginary > 0)
    if pair.size:
        V[:, pair] += 1j * vectors[:, pair + 1]
        V[:, pair + 1] = np.conj(V[:, pair])
    lu, pivots, singular = lapack.zgetrf(V)
    if singular:
        return grows, NO_BASIS
    return grows, (V, lapack.zgetri(lu, pivots)[0])


@njit(cache=True)
def _certified(data, indptr, indices, steps, candidates, V, W, Z):
    """How many of the ``candidates`` (in order) have Re z <= SPANNED for every eigenvalue
    of Z = K J certified by Gershgorin's bound scaled at best: the spectral abscissa of the
    comparison matrix C (C_ii = Re Z_ii, C_ij = |Z_ij|) bounds Re z (the Gershgorin bound of
    D^-1 Z D, minimized over diagonal D > 0), first of Z, then of B = W Z V (``V``, ``W``: a
    basis and its inverse, empty where there is none), with B's distance to V^-1 Z V added
    to C: |R| |B| (R = W V - I: W's rounding) and the products' rounding,
    2 N eps |W| |Z| |V|.
    ``Z``: (N, N), holds the Z of the step not certified."""
    N = indptr.size - 1
    C, A = np.zeros((N, N)), np.zeros((N, N))
    B, T = np.zeros((N, N), dtype=np.complex128), np.zeros((N, N), dtype=np.complex128)
    # (loops, not numpy's reductions: they cost seconds of compile)
    n = V.shape[0]
    absV, sum_W, sum_R = np.empty((n, n)), np.zeros(n), np.zeros(n)
    for i in range(n):
        for j in range(n):
            absV[i, j] = abs(V[i, j])
            sum_W[i] += abs(W[i, j])
            entry = -1.0 + 0j if i == j else 0j
            for k in range(n):
                entry += W[i, k] * V[k, j]
            sum_R[i] += abs(entry)
    rounding = 2 * N * EPS
    for count in range(candidates.size):
        p = candidates[count]
        Z[:] = 0.0
        for i in range(N):
            for m in range(indptr[i], indptr[i + 1]):
                Z[i, indices[m]] = steps[p, i] * data[p, m]
        for i in range(N):
            for j in range(N):
                C[i, j] = Z[i, j] if i == j else abs(Z[i, j])
        if _abscissa_below(C, SPANNED):
            continue
        if V.shape[0] == 0:
            return count
        T[:] = 0.0
        A[:] = 0.0
        for i in range(N):
            for k in range(N):
                if Z[i, k] != 0.0:
                    for j in range(N):
                        T[i, j] += Z[i, k] * V[k, j]
                        A[i, j] += abs(Z[i, k]) * absV[k, j]
        B[:] = 0.0
        for i in range(N):
            for k in range(N):
                for j in range(N):
                    B[i, j] += W[i, k] * T[k, j]
        # (X Y)_ij <= (sum_k X_ik) max_k Y_kj for X, Y >= 0: the margins in N^2
        for j in range(N):
            top_A = top_B = 0.0
            for k in range(N):
                top_A, top_B = max(top_A, A[k, j]), max(top_B, abs(B[k, j]))
            for i in range(N):
                C[i, j] = rounding * sum_W[i] * top_A + sum_R[i] * top_B + (
                    B[i, j].real if i == j else abs(B[i, j]))
        if not _abscissa_below(C, SPANNED):
            return count
    return candidates.size


@njit(cache=True)
def _abscissa_below(C, s):
    """Whether the spectral abscissa of C (off-diagonal entries >= 0: a Metzler matrix) is
    below s: A = s I - C (off-diagonal entries <= 0) is then a nonsingular M-matrix, which
    is where its elimination without pivoting has positive pivots (its leading principal
    minors; each Schur complement keeps the sign pattern). C is overwritten."""
    N = C.shape[0]
    for i in range(N):
        for j in range(N):
            C[i, j] = (s if i == j else 0.0) - C[i, j]
    for k in range(N):
        pivot = C[k, k]
        if not pivot > 0.0:
            return False
        for i in range(k + 1, N):
            factor = C[i, k] / pivot
            if factor != 0.0:
                for j in range(k + 1, N):
                    C[i, j] -= factor * C[k, j]
    return True


def _missed(Z, g, U, atol, rtol, num, den):
    """(c, z, log10 ratio, i) of the mode of the matrices ``Z`` (P, N, N) = K J (Re z >
    SPANNED) whose step error a |exp(z) - R(z)| |v_i| / (atol_i + rtol |U_i|), a = |w^T K f|
    / |z| (``g`` = K f, (P, N)), is largest over the P steps and the modes, where its ratio
    exceeds MISSED; None otherwise."""
    with np.errstate(all="ignore"):
        z, V = np.linalg.eig(Z)
        try:
            W = np.linalg.inv(V)
        except np.linalg.LinAlgError:  # (a defective Z: the modes its basis has)
            W = np.linalg.pinv(V)
        amplitude = np.abs(np.einsum("pjn,pn->pj", W, g)) / np.abs(z)
        # log|exp(z) - R(z)| = Re z + log|1 - R(z) exp(-z)|: finite past exp's range
        R = np.polyval(num[::-1], z) / np.polyval(den[::-1], z)
        carried = np.where(z.real < 700, R * np.exp(np.minimum(-z.real, 0) - 1j * z.imag), 0)
        gap = np.where(np.isfinite(carried), z.real + np.log(np.abs(1.0 - carried)), np.inf)
        scale = np.abs(V) / (atol + rtol * np.abs(U))[:, :, None]  # (P, i, mode)
        ratio = (np.log(amplitude * scale.max(axis=1)) + gap) / np.log(10.0)
        ratio = np.where((z.real > SPANNED) & ~np.isnan(ratio), ratio, -np.inf)
    c, j = np.unravel_index(np.argmax(ratio), ratio.shape)
    if ratio[c, j] <= np.log10(MISSED):
        return None
    return int(c), complex(z[c, j]), float(ratio[c, j]), int(np.argmax(scale[c, :, j]))


def message(ode, m, found):
    """The ToleranceWarning's text for :func:`spanned_growth`'s ``found`` of a solve of
    ``ode`` by ``m``: the cause, and the step bound that resolves the mode, or where its
    growth to T is past double precision, that no step does."""
    t, z, ratio, i, k = found
    rate, name = z.real / k, ode.states[i].name
    family = "L-stable, damps it" if m.family == "dG" else "A-stable, does not grow it"
    growth = rate * (ode.T - t)
    size = f"{10 ** ratio:.3g} x" if ratio < 300 else f"10^{ratio:.3g} x"
    if growth > np.log(np.finfo(float).max):
        what = (f"exp(lambda (T - t)) = exp({growth:.3g}) is past double precision: no step "
                f"resolves it; check the model, its scaling or its parameters")
    else:
        what = (f"give maximum_time_step below 1 / lambda (e.g. {0.1 / rate:.3g}), or an "
                f"absolute_tolerance below the mode's amplitude")
    return (f"a growing mode of the Jacobian (rate lambda = {rate:.3g}, mostly in {name}) "
            f"spans the step k = {k:.3g} at t = {t:.6g} (k lambda = {z.real:.3g}): the exact "
            f"solution grows by exp({z.real:.3g}) over it where the discrete one ({m.name}, "
            f"{family}) does not, and the step control does not see it below the tolerance "
            f"(the step's error in that mode is {size} the tolerance). The solution "
            f"from t = {t:.6g} on may be wrong at any tolerance: {what}")
