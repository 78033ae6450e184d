"""Newton matrices of a group of components on one interval: the sub-slabs of the
multi-adaptive loop, solved together by simplified Newton and filtered together by the error
estimate.

The group's components are put in the global bandwidth ordering (``group_order``); their
rows of df/du restricted to them, J_gg, have band widths (kl, ku) at most the global ones
(``group_band``). For each eigenvalue lambda of the stage matrix A = T B T^{-1} the matrix
I - k lambda J_gg is assembled in band storage (``assemble_group``) and factored
(``factor_group``); ``solve_group`` solves (I - k A (x) J_gg) dX = r with them by RADAU5's
transformation, as the mono-adaptive solver (:mod:`dolfinode.solvers.slab`) does with the
whole system's matrices.
"""
import numpy as np

from dolfinode.compile.jit import helper, linked
from dolfinode.counters import FACTORIZATIONS
from dolfinode.linalg.banded import band_lu, band_solve
from dolfinode.methods.method import real_eigenvalues


@helper(inline="always")
def group_order(elist, n, comp, position, order, local):
    """The components of the elements elist[:n] in the global bandwidth ordering into
    order[:n], and local[i] = their row block (the others stay -1)."""
    for r_ in range(n):
        order[r_] = comp[elist[r_]]
    for a_ in range(1, n):  # insertion sort by global position (groups are small or sorted)
        c = order[a_]
        b_ = a_ - 1
        while b_ >= 0 and position[order[b_]] > position[c]:
            order[b_ + 1] = order[b_]
            b_ -= 1
        order[b_ + 1] = c
    for r_ in range(n):
        local[order[r_]] = r_


@helper()
def group_band(order, n, local, indptr, indices):
    """The band widths (kl, ku) of J_gg, the rows of the components order[:n] restricted to
    them, in their order (``local``, see ``group_order``). (Not inlined: the literal 0 its
    widths start from would reach band_lu's types and compile it once more.)"""
    kl = 0
    ku = 0
    for r_ in range(n):
        i = order[r_]
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if local[j] >= 0:
                kl = max(kl, local[i] - local[j])
                ku = max(ku, local[j] - local[i])
    return kl, ku


@helper(inline="always")
def band_view(matrices, j, n, width):
    """Band matrix j of a group workspace (``group_workspace``) for n rows of ``width``: a
    C-contiguous (n, width) view, so that band_lu and band_solve take the types they take
    for the mono-adaptive loop (and are compiled once for both)."""
    return matrices[j, :n * width].reshape((n, width))


@helper()
def assemble_group(order, n, local, indptr, indices, jacobian, c, kl, ku, ab):
    """I - c J_gg into the band storage ab (n rows, real or complex c), J_gg as in
    ``group_band``."""
    kv = kl + ku
    ab[:, :] = 0.0
    for r_ in range(n):
        i = order[r_]
        for nz in range(indptr[i], indptr[i + 1]):
            j = indices[nz]
            if local[j] >= 0:
                ab[local[j], kv + r_ - local[j]] -= c * jacobian[nz]
    for r_ in range(n):
        ab[r_, kv] += 1.0


@linked
@helper()
def factor_group(order, n, local, indptr, indices, jacobian, k, eigenvalues, newton,
                 counters):
    """Factor I - k lambda J_gg (``group_band``) in band storage for every eigenvalue lambda
    of the stage matrix: the real ones into the real matrices of the workspace ``newton``,
    one complex matrix per complex pair (see ``group_newton``). Returns the band widths and
    0, or band_lu's info of a singular matrix."""
    ab_real, ab_complex, ipiv = newton[0], newton[1], newton[2]
    kl, ku = group_band(order, n, local, indptr, indices)
    width = 2 * kl + ku + 1  # the workspace fits: local bands <= global ones
    real = real_eigenvalues(eigenvalues)
    for j in range(real):
        counters[FACTORIZATIONS] += 1
        assemble_group(order, n, local, indptr, indices, jacobian, k * eigenvalues[j].real,
                       kl, ku, band_view(ab_real, j, n, width))
        info = band_lu(band_view(ab_real, j, n, width), kl, ku, ipiv[j])
        if info != 0:
            return kl, ku, info
    for j in range(real, eigenvalues.shape[0]):
        counters[FACTORIZATIONS] += 1
        assemble_group(order, n, local, indptr, indices, jacobian, k * eigenvalues[j], kl, ku,
                       band_view(ab_complex, j - real, n, width))
        info = band_lu(band_view(ab_complex, j - real, n, width), kl, ku, ipiv[j])
        if info != 0:
            return kl, ku, info
    return kl, ku, 0


@helper(inline="always")
def solve_group(n, kl, ku, stages, newton):
    """(I - k A (x) J_gg) dX = r for the stage-major residuals r = rhs[s n + r_] (in place),
    with the factors of ``factor_group``: A = T B T^{-1} (``stages`` = (T, T^{-1}, the
    eigenvalues)) turns it into (I - k B (x) J_gg) Z = (T^{-1} (x) I) r, one n x n system per
    real eigenvalue and one complex per pair (whose two real blocks are the real and imaginary
    parts of one complex vector), and dX = (T (x) I) Z: RADAU5's transformation, as in the
    mono-adaptive loop. A group of n components with band b costs ~S/2 n x n band
    factorizations of O(n b^2) instead of one S n x S n of O(n (S b)^2)."""
    T, T_inverse, eigenvalues = stages
    ab_real, ab_complex, ipiv, rhs, z_real, z_complex, Z = newton
    S = T.shape[0]
    width = 2 * kl + ku + 1
    for j in range(S):  # Z = (T^{-1} (x) I) r
        for r_ in range(n):
            acc = 0.0
            for s_ in range(S):
                acc += T_inverse[j, s_] * rhs[s_ * n + r_]
            Z[j, r_] = acc
    real = real_eigenvalues(eigenvalues)
    for j in range(real):
        for r_ in range(n):
            z_real[r_] = Z[j, r_]
        band_solve(band_view(ab_real, j, n, width), kl, ku, ipiv[j], z_real[:n])
        for r_ in range(n):
            Z[j, r_] = z_real[r_]
    for c in range(eigenvalues.shape[0] - real):
        re = real + 2 * c
        for r_ in range(n):
            z_complex[r_] = complex(Z[re, r_], Z[re + 1, r_])
        band_solve(band_view(ab_complex, c, n, width), kl, ku, ipiv[real + c], z_complex[:n])
        for r_ in range(n):
            Z[re, r_] = z_complex[r_].real
            Z[re + 1, r_] = z_complex[r_].imag
    for s_ in range(S):  # dX = (T (x) I) Z
        for r_ in range(n):
            acc = 0.0
            for j in range(S):
                acc += T[s_, j] * Z[j, r_]
            rhs[s_ * n + r_] = acc


@helper()
def group_workspace(real, pairs, S, rows, width):
    """The workspace of ``group_newton`` for groups of up to ``rows`` components: (real band
    matrices, complex ones, pivots, rhs, real vector, complex vector, Z). Matrix j is
    ``band_view(matrices, j, n, width)``."""
    real_ab = np.empty((real, rows * width))
    complex_ab = np.empty((pairs, rows * width), dtype=np.complex128)
    pivots = np.empty((max(real, S), rows), dtype=np.int64)
    # (zeroed by loops: numba compiles np.zeros's implementation once more for every type)
    for m in range(real):
        for j in range(rows * width):
            real_ab[m, j] = 0.0
    for m in range(pairs):
        for j in range(rows * width):
            complex_ab[m, j] = 0.0
    for m in range(pivots.shape[0]):
        for j in range(rows):
            pivots[m, j] = 0
    return (real_ab, complex_ab, pivots, np.empty(S * rows), np.empty(rows),
            np.empty(rows, dtype=np.complex128), np.empty((S, rows)))
