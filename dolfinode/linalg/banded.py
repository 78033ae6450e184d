"""Banded LU factorisation with partial pivoting (LAPACK's gbtf2/gbtrs), compiled with numba.

A sparse Jacobian ordered by reverse Cuthill-McKee has a narrow band; the Newton matrix of a
time slab inherits it, so a banded direct solve costs O(n b^2) and stays cacheable by numba
(which LAPACK function pointers would prevent). A dense matrix is the case b = n - 1.

Storage: ``ab[j, kl + ku + i - j] = A[i, j]`` for max(0, j - ku) <= i <= min(n - 1, j + kl);
the first kl entries of every column hold fill-in from row interchanges. The factors keep
1 / U[j, j] on the diagonal (unlike LAPACK): the back substitution multiplies, where a division
(~4x a multiplication's latency) sat on its dependency chain.
"""
import numpy as np
import scipy.sparse as sps
from numba import njit
from scipy.sparse.csgraph import reverse_cuthill_mckee

from dolfinode.compile.jit import linked
from dolfinode.compile.signatures import NO_REFCOUNT

#: Column indices of the band storage are cast to unsigned in the inner loops: numba wraps a
#: signed index around (i < 0: i + n), a select that keeps LLVM from vectorizing the loop;
#: an unsigned one it takes as is (the same results: the updates of each entry keep their
#: order).
_u = np.uint64


def band_storage(n, kl, ku):
    """Zeroed band storage for an n x n matrix with kl sub- and ku super-diagonals."""
    return np.zeros((n, 2 * kl + ku + 1))


@njit(cache=True, inline="always")
def _magnitude(a):
    """|Re a| + |Im a|: the pivot size of LAPACK's complex routines (cabs1), without the
    square root of abs(); abs(a) for real a."""
    return abs(a.real) + abs(a.imag)


@linked
@njit(cache=True, **NO_REFCOUNT)
def band_lu(ab, kl, ku, ipiv):
    """Factor the band matrix (real or complex) in place, P A = L U. Returns 0, or j + 1 if
    U[j, j] is zero."""
    n = ab.shape[0]
    kv = ku + kl
    for j in range(n):
        for i in range(kl):
            ab[j, i] = 0.0  # fill-in rows start at zero (they are not part of A)
    info = 0
    ju = 0
    for j in range(n):
        km = min(kl, n - 1 - j)
        jp = 0
        big = _magnitude(ab[j, kv])
        for i in range(1, km + 1):
            if _magnitude(ab[j, kv + i]) > big:
                big = _magnitude(ab[j, kv + i])
                jp = i
        ipiv[j] = j + jp
        if ab[j, kv + jp] == 0.0:
            if info == 0:
                info = j + 1
            continue
        ju = max(ju, min(j + ku + jp, n - 1))
        if jp != 0:
            for c in range(ju - j + 1):
                tmp = ab[j + c, kv + jp - c]
                ab[j + c, kv + jp - c] = ab[j + c, kv - c]
                ab[j + c, kv - c] = tmp
        rp = 1.0 / ab[j, kv]
        ab[j, kv] = rp
        if km > 0:
            for i in range(1, km + 1):
                ab[j, _u(kv + i)] *= rp
            for c in range(1, ju - j + 1):
                a_rj = ab[j + c, kv - c]
                if a_rj != 0.0:
                    for i in range(1, km + 1):
                        ab[j + c, _u(kv - c + i)] -= ab[j, _u(kv + i)] * a_rj
    return info


@njit(cache=True, **NO_REFCOUNT)
def band_solve(ab, kl, ku, ipiv, b):
    """Solve A x = b in place with the factors from :func:`band_lu`."""
    n = ab.shape[0]
    kv = ku + kl
    for j in range(n - 1):
        lm = min(kl, n - 1 - j)
        piv = ipiv[j]
        if piv != j:
            tmp = b[piv]
            b[piv] = b[j]
            b[j] = tmp
        bj = b[j]
        if bj != 0.0:
            for i in range(1, lm + 1):
                b[_u(j + i)] -= ab[j, _u(kv + i)] * bj
    for j in range(n - 1, -1, -1):
        b[j] *= ab[j, kv]
        bj = b[j]
        if bj != 0.0:
            for i in range(max(0, j - kv), j):
                b[_u(i)] -= ab[j, _u(kv + i - j)] * bj


def bandwidth_ordering(indptr, indices, n):
    """Component ordering that narrows the band of a sparsity pattern.

    Returns (order, position, kl, ku): ``order[r]`` is the component at position r,
    ``position[i]`` the position of component i, and kl/ku the lower/upper bandwidths in
    that ordering. Reverse Cuthill-McKee is used when it narrows the band.
    """
    pattern = sps.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
    candidates = [np.arange(n)]
    if n > 2:
        candidates.append(np.asarray(reverse_cuthill_mckee((pattern + pattern.T).tocsr(),
                                                           symmetric_mode=True), dtype=np.int64))
    best = None
    rows = np.repeat(np.arange(n), np.diff(indptr))
    for order in candidates:
        position = np.empty(n, dtype=np.int64)
        position[order] = np.arange(n)
        offset = position[rows] - position[indices]
        kl = int(max(offset.max(initial=0), 0))
        ku = int(max(-offset.min(initial=0), 0))
        if best is None or kl + ku < best[2] + best[3]:
            best = (order.astype(np.int64), position, kl, ku)
    return best
