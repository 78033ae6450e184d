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

from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT

#: Column indices of the band storage are cast to unsigned in the inner loops: numba wraps a
#: signed index around (i < 0: i + n), a select that keeps LLVM from vectorizing the loop;
#: an unsigned one it takes as is (the same results: the updates of each entry keep their
#: order).
_u = np.uint64
#: Bandwidths up to which a solve without row interchanges carries the unknowns in registers
#: (:func:`_narrow_solve`): interleaved 1-D couplings (two species: kl = ku = 2).
NARROW = 2


def band_storage(n, kl, ku):
    """Zeroed band storage for an n x n matrix with kl sub- and ku super-diagonals."""
    return np.zeros((n, 2 * kl + ku + 1))


@njit(cache=True, inline="always")
def _magnitude(a):
    """|Re a| + |Im a|: the pivot size of LAPACK's complex routines (cabs1), without the
    square root of abs(); abs(a) for real a."""
    return abs(a.real) + abs(a.imag)


@helper(**NO_REFCOUNT)
def _narrow_lu(ab, kl, ku, ipiv):
    """The columns of :func:`band_lu` for kl, ku <= NARROW while no row interchange is needed
    (|A[j, j]| the largest of its column, as in diagonally dominant Newton matrices):
    unrolled, where the general loops' short variable-length inner loops cost most of the
    time. Returns the first column that needs an interchange or has a zero pivot (n: none),
    from which the general loop takes over."""
    n = ab.shape[0]
    kv = ku + kl
    for j in range(n):
        d = ab[j, kv]
        big = _magnitude(d)
        if big == 0.0:
            return j
        km = min(kl, n - 1 - j)
        if km >= 1 and _magnitude(ab[j, kv + 1]) > big:
            return j
        if km >= 2 and _magnitude(ab[j, kv + 2]) > big:
            return j
        ipiv[j] = j
        r = 1.0 / d
        ab[j, kv] = r
        if km == 0:
            continue
        l1 = ab[j, kv + 1] * r
        ab[j, kv + 1] = l1
        l2 = l1 * 0.0
        if km == 2:
            l2 = ab[j, kv + 2] * r
            ab[j, kv + 2] = l2
        for c in range(1, min(ku, n - 1 - j) + 1):
            a_rj = ab[j + c, kv - c]
            ab[j + c, kv - c + 1] -= l1 * a_rj
            if km == 2:
                ab[j + c, kv - c + 2] -= l2 * a_rj
    return n


@linked
@helper(**NO_REFCOUNT)
def band_lu(ab, kl, ku, ipiv):
    """Factor the band matrix (real or complex) in place, P A = L U. Returns 0, or j + 1 if
    U[j, j] is zero."""
    n = ab.shape[0]
    kv = ku + kl
    for j in range(n):
        for i in range(kl):
            ab[j, i] = 0.0  # fill-in rows start at zero (they are not part of A)
    start = _narrow_lu(ab, kl, ku, ipiv) if kl <= NARROW and ku <= NARROW else 0
    info = 0
    ju = min(start - 1 + ku, n - 1)  # the columns so far had no interchange
    for j in range(start, n):
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


@helper(**NO_REFCOUNT)
def _interchanged(ipiv):
    """Whether the factorization interchanged any rows (ipiv[j] != j for some j)."""
    for j in range(ipiv.shape[0]):
        if ipiv[j] != j:
            return True
    return False


@helper(**NO_REFCOUNT)
def _narrow_solve(ab, kl, ku, b):
    """:func:`band_solve` for kl, ku <= NARROW and factors without row interchanges, by rows:

        y_j = b_j - sum_(i=1..kl) L[j, j-i] y_(j-i),  x_j = (y_j - sum_(i=1..ku) U[j, j+i]
        x_(j+i)) / U[j, j],

    the last two unknowns carried in registers, the terms subtracted in the column sweeps'
    order (the same results). The column sweeps pass every unknown through memory (a store,
    then a load on the next row: a recurrence bound by latency, 1.5x (real) and 2x
    (complex) slower on the 1-D Brusselator's Newton matrices)."""
    n = ab.shape[0]
    kv = ku + kl
    y1 = y2 = b[0] * 0.0  # y_(j-1), y_(j-2); zero of b's type
    for j in range(n):
        v = b[j]
        if j >= 2 and kl == 2:
            v -= ab[j - 2, kv + 2] * y2
        if j >= 1 and kl >= 1:
            v -= ab[j - 1, kv + 1] * y1
        b[j] = v
        y2 = y1
        y1 = v
    x1 = x2 = b[0] * 0.0  # x_(j+1), x_(j+2)
    for j in range(n - 1, -1, -1):
        v = b[j]
        if j + 2 < n and ku == 2:
            v -= ab[j + 2, kv - 2] * x2
        if j + 1 < n and ku >= 1:
            v -= ab[j + 1, kv - 1] * x1
        v *= ab[j, kv]
        b[j] = v
        x2 = x1
        x1 = v


@helper(**NO_REFCOUNT)
def band_solve(ab, kl, ku, ipiv, b):
    """Solve A x = b in place with the factors from :func:`band_lu`."""
    n = ab.shape[0]
    kv = ku + kl
    if kl <= NARROW and ku <= NARROW and n > 0 and not _interchanged(ipiv):
        _narrow_solve(ab, kl, ku, b)
        return
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
