"""Sparse LU with static pivots: its filled pattern, its factors and solves against numpy, and the
fill-reducing ordering."""
import numpy as np
import pytest
import scipy.sparse as sps

from dolfinode.linalg.sparse import (
    fill_reducing_ordering,
    lu_flops,
    sparse_lu,
    sparse_solve,
    symbolic_lu,
)


def grid_pattern(n):
    """The 5-point stencil on an n x n grid (CSR, diagonal included)."""
    one = sps.diags([1.0, 1.0, 1.0], [-1, 0, 1], shape=(n, n))
    return (sps.kron(one, sps.identity(n)) + sps.kron(sps.identity(n), one)).tocsr()


def random_pattern(rng, n, density):
    """An unsymmetric random pattern with the diagonal."""
    pattern = sps.random(n, n, density=density, random_state=rng, format="csr")
    return (pattern + sps.identity(n)).tocsr()


def arrow_pattern(n):
    """Diagonal, first row and first column: eliminated first, the first row fills everything."""
    A = np.eye(n)
    A[0, :] = A[:, 0] = 1.0
    return sps.csr_matrix(A)


PATTERNS = {
    "grid 6 x 6": lambda rng: grid_pattern(6),
    "random 40": lambda rng: random_pattern(rng, 40, 0.08),
    "random 7 dense": lambda rng: random_pattern(rng, 7, 0.9),
    "diagonal 5": lambda rng: sps.identity(5, format="csr"),
    "arrow 12": lambda rng: arrow_pattern(12),
}


def filled(pattern):
    """(ptr, idx, diag) of a pattern in its own order (symmetrized)."""
    n = pattern.shape[0]
    symmetric = (abs(pattern) + abs(pattern.T) + sps.identity(n)).tocsr()
    symmetric.sort_indices()
    return symbolic_lu(symmetric.indptr.astype(np.int64), symmetric.indices.astype(np.int64), n)


def storage(A, ptr, idx):
    """A's entries in the filled pattern (zeros at the fill)."""
    values = np.zeros(len(idx), dtype=A.dtype)
    for i in range(A.shape[0]):
        values[ptr[i]:ptr[i + 1]] = A[i, idx[ptr[i]:ptr[i + 1]]]
    return values


def dominant(rng, pattern, dtype):
    """A matrix with the pattern, diagonally dominant by rows, real or complex."""
    A = pattern.toarray() != 0
    values = rng.standard_normal(A.shape)
    if dtype is complex:
        values = values + 1j * rng.standard_normal(A.shape)
    M = np.where(A, values, 0.0)
    np.fill_diagonal(M, 0.0)
    np.fill_diagonal(M, np.abs(M).sum(axis=1) + 1.0)
    return M


@pytest.mark.parametrize("name", PATTERNS)
def test_filled_pattern_is_that_of_dense_elimination(name):
    """The symbolic pattern is exactly the set of entries that Gaussian elimination without
    interchanges can make nonzero: L + U of a matrix with random entries on the pattern."""
    rng = np.random.default_rng(3)
    pattern = PATTERNS[name](rng)
    n = pattern.shape[0]
    ptr, idx, diag = filled(pattern)
    M = dominant(rng, pattern + pattern.T, float)
    LU = M.copy()
    for k in range(n):
        LU[k + 1:, k] /= LU[k, k]
        LU[k + 1:, k + 1:] -= np.outer(LU[k + 1:, k], LU[k, k + 1:])
    expected = np.abs(LU) > 1e-14
    got = np.zeros((n, n), dtype=bool)
    for i in range(n):
        cols = idx[ptr[i]:ptr[i + 1]]
        assert np.all(np.diff(cols) > 0)  # sorted, no repeats
        assert cols[diag[i] - ptr[i]] == i
        got[i, cols] = True
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("dtype", [float, complex])
@pytest.mark.parametrize("name", PATTERNS)
def test_factor_and_solve_match_numpy(name, dtype):
    rng = np.random.default_rng(4)
    pattern = PATTERNS[name](rng)
    n = pattern.shape[0]
    ptr, idx, diag = filled(pattern)
    M = dominant(rng, pattern, dtype)
    values = storage(M, ptr, idx)
    assert sparse_lu(values, ptr, idx, diag) == 0
    b = rng.standard_normal(n).astype(dtype)
    x = b.copy()
    sparse_solve(values, ptr, idx, diag, x)
    np.testing.assert_allclose(x, np.linalg.solve(M, b), rtol=1e-12, atol=1e-12)


def test_a_zero_pivot_is_reported():
    """Without interchanges a zero pivot cannot be stepped over: the row is returned (1-based),
    as LAPACK's info."""
    M = np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 1.0], [0.0, 1.0, 3.0]])  # U[1, 1] = 0
    ptr, idx, diag = filled(sps.csr_matrix(M))
    assert sparse_lu(storage(M, ptr, idx), ptr, idx, diag) == 2
    one = filled(sps.identity(1, format="csr"))
    assert sparse_lu(np.array([np.nan]), *one) == 1  # nor a pivot that is not finite


def ordered_and_natural(pattern):
    n = pattern.shape[0]
    position = fill_reducing_ordering(pattern.indptr, pattern.indices, n)
    np.testing.assert_array_equal(np.sort(position), np.arange(n))
    P = sps.csr_matrix((np.ones(n), (position, np.arange(n))), shape=(n, n))
    return filled((P @ pattern @ P.T).tocsr()), filled(pattern)


def test_ordering_reduces_fill():
    """Minimum degree: on a 20 x 20 grid factors with less than half the entries and a third
    of the multiply-adds of the natural (banded) order's (6944 against 15638, 42024 against
    149739); an arrow's hub goes last, so nothing fills in (3 n - 2 entries, not n^2)."""
    ordered, natural = ordered_and_natural(grid_pattern(20))
    assert len(ordered[1]) < 0.5 * len(natural[1])
    assert lu_flops(*ordered) < 0.35 * lu_flops(*natural)
    ordered, natural = ordered_and_natural(arrow_pattern(12))
    assert len(natural[1]) == 12 * 12
    assert len(ordered[1]) == 3 * 12 - 2
