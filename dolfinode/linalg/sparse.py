"""Sparse LU with static diagonal pivots on a fill-reducing ordering, compiled with numba;
and when the dual's stage systems leave the banded LU for scipy's SuperLU.

The banded LU of :mod:`dolfinode.linalg.banded` costs O(n b^2) for n unknowns and band b; on
chains b is a few, on 2-D lattices it grows like sqrt(N) and a fill-reducing sparse LU is much
faster. Newton matrices I - c J (Re c >= 0, J the Jacobian of a stiff system) are factored
here in the symmetric ordering that SuperLU's minimum degree on J + J^T gives, without row
interchanges: the filled pattern (that of the Cholesky factor of the symmetrized pattern) is
then known before any values, and the factorization is Gaussian elimination row by row
(IKJ) into it. Pivots are not sought, a zero one fails the factorization (Newton's step is
then shortened), a small one costs Newton iterations, not accuracy.

Storage: ``values[ptr[i]:ptr[i + 1]]`` holds row i of L (strictly lower, unit diagonal not
stored), then U's diagonal at ``diag[i]``, then U's strictly upper part, columns ``idx`` in
increasing order; the factors keep 1 / U[i, i] on the diagonal, as the banded LU does.
"""
import numpy as np
import scipy.sparse as sps
from numba import njit
from scipy.sparse.linalg import splu

from dolfinode.compile.jit import helper
from dolfinode.compile.signatures import NO_REFCOUNT

#: splu is used when the stage matrix's band r (kl + ku + 2) exceeds this ...
SPARSE_BAND = 200
#: ... and it has at least this many unknowns (below, the Python loop over intervals of the
#: sparse path costs more than the factorisations).
SPARSE_MINIMUM = 1000


def wide_band(n_unknowns, band):
    """Whether a stage system I - h (A (x) I) diag(J_m) with ``n_unknowns`` = r N unknowns and
    total band ``band`` (in the Jacobian's bandwidth ordering) is solved faster by scipy's
    splu than by the compiled banded LU of :mod:`dolfinode.linalg.banded`.

    The banded LU costs about 0.2 us + 3.5e-11 band^2 s per unknown, splu 1-8 us per unknown
    (1-D chains to 2-D lattices), so the crossover is at a band of about 170-290: the banded
    LU stays faster on chains, splu on 2-D lattices (doc/benchmarks/dual_lu.md).
    """
    return n_unknowns >= SPARSE_MINIMUM and band > SPARSE_BAND


def fill_reducing_ordering(indptr, indices, n):
    """``position[i]``, the place of component i in the ordering that SuperLU's multiple
    minimum degree on the pattern of J + J^T chooses (``permc_spec="MMD_AT_PLUS_A"``), read
    from a factorization of the diagonally dominant I - S / (2 max_i sum_j S_ij), S that
    pattern (a symmetric permutation: scipy's splu returns P_r A P_c = L U with column j of A
    at place ``perm_c[j]``)."""
    pattern = sps.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
    pattern = (pattern + pattern.T).tocsc()
    scale = 0.5 / max(1.0, float(pattern.sum(axis=1).max()))
    lu = splu((sps.identity(n, format="csc") - scale * pattern).tocsc(),
              permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
              options={"SymmetricMode": True})
    return np.asarray(lu.perm_c, dtype=np.int64)


@njit(cache=True)
def symbolic_lu(sptr, sidx, n):
    """The filled pattern of the LU factors of a matrix with the symmetric pattern (sptr,
    sidx) (CSR, diagonal included), eliminated in its order without interchanges.

    Row i of L is the set of nodes on the paths of the elimination tree from each j < i with
    S_ij != 0 up to i (Liu's row subtrees; the tree by Liu's algorithm with path compression);
    U's pattern is L's transposed. Returns (ptr, idx, diag) in the storage of the module
    docstring."""
    parent = np.full(n, -1, np.int64)
    ancestor = np.full(n, -1, np.int64)
    for i in range(n):
        for p in range(sptr[i], sptr[i + 1]):
            j = sidx[p]
            while j != -1 and j < i:
                up = ancestor[j]
                ancestor[j] = i
                if up == -1:
                    parent[j] = i
                j = up
    mark = np.full(n, -1, np.int64)
    lower = np.zeros(n + 1, np.int64)  # L's rows: first their lengths, then pointers
    for sweep in range(2):
        if sweep == 1:
            for i in range(n):
                lower[i + 1] += lower[i]
            rows = np.empty(lower[n], np.int64)
            upper = np.zeros(n, np.int64)
            mark[:] = -1
        for i in range(n):
            mark[i] = i
            q = lower[i]
            for p in range(sptr[i], sptr[i + 1]):
                j = sidx[p]
                while j < i and mark[j] != i:
                    mark[j] = i
                    if sweep == 0:
                        lower[i + 1] += 1
                    else:
                        rows[q] = j
                        q += 1
                        upper[j] += 1
                    j = parent[j]
            if sweep == 1:
                rows[lower[i]:lower[i + 1]].sort()
    ptr = np.zeros(n + 1, np.int64)
    for i in range(n):
        ptr[i + 1] = ptr[i] + (lower[i + 1] - lower[i]) + 1 + upper[i]
    idx = np.empty(ptr[n], np.int64)
    diag = np.empty(n, np.int64)
    for i in range(n):
        q = ptr[i]
        for p in range(lower[i], lower[i + 1]):
            idx[q] = rows[p]
            q += 1
        diag[i] = q
        idx[q] = i
        upper[i] = q + 1  # next free place of row i's U part
    for i in range(n):  # U's rows are L's columns, met in increasing order of i
        for p in range(lower[i], lower[i + 1]):
            j = rows[p]
            idx[upper[j]] = i
            upper[j] += 1
    return ptr, idx, diag


@njit(cache=True)
def lu_flops(ptr, idx, diag):
    """Multiply-adds of :func:`sparse_lu` on the pattern: sum over the entries L_ik of the
    length of U's row k."""
    total = 0
    for i in range(diag.shape[0]):
        for p in range(ptr[i], diag[i]):
            k = idx[p]
            total += ptr[k + 1] - diag[k] - 1
    return total


# allocates its work row: reference counting stays on when the factorizations (compiled
# without it, NO_REFCOUNT, an option numba passes on to the functions they call) call it
@helper(_nrt=True)
def sparse_lu(values, ptr, idx, diag):
    """Factor in place, A = L U (real or complex), row by row: row i is scattered into a
    dense work row w, w_k <- w_k / U_kk and w <- w - w_k U_k. for its L columns k in
    increasing order, and gathered back. Returns 0, or i + 1 if U[i, i] is zero or not
    finite."""
    n = diag.shape[0]
    w = np.zeros(n, dtype=values.dtype)
    for i in range(n):
        for p in range(ptr[i], ptr[i + 1]):
            w[idx[p]] = values[p]
        for p in range(ptr[i], diag[i]):
            k = idx[p]
            lik = w[k] * values[diag[k]]
            w[k] = lik
            if lik != 0.0:
                for q in range(diag[k] + 1, ptr[k + 1]):
                    w[idx[q]] -= lik * values[q]
        for p in range(ptr[i], ptr[i + 1]):
            values[p] = w[idx[p]]
        pivot = values[diag[i]]
        if pivot == 0.0 or not np.isfinite(pivot):
            return i + 1
        values[diag[i]] = 1.0 / pivot
    return 0


@helper(**NO_REFCOUNT)
def sparse_solve(values, ptr, idx, diag, b):
    """Solve A x = b in place with the factors of :func:`sparse_lu`: L y = b forward, then
    U x = y backward."""
    n = diag.shape[0]
    for i in range(n):
        s = b[i]
        for p in range(ptr[i], diag[i]):
            s -= values[p] * b[idx[p]]
        b[i] = s
    for i in range(n - 1, -1, -1):
        s = b[i]
        for p in range(diag[i] + 1, ptr[i + 1]):
            s -= values[p] * b[idx[p]]
        b[i] = s * values[diag[i]]
