"""Banded LU with partial pivoting against numpy, and the bandwidth-reducing ordering."""
import numpy as np
import pytest
import scipy.sparse as sps

from dolfinode.linalg import band_lu, band_solve, band_storage, bandwidth_ordering


def random_banded(rng, n, kl, ku, zero_diagonal=False):
    """Dense n x n matrix with kl sub- and ku super-diagonals of random entries."""
    A = rng.standard_normal((n, n))
    i, j = np.indices((n, n))
    A[(i - j > kl) | (j - i > ku)] = 0.0
    if zero_diagonal:
        A[i == j] = 0.0
    else:
        A += np.diag(np.sign(np.diag(A)) * 0.5)  # keep away from singular without making it easy
    return A


def to_band(A, kl, ku, fill=0.0):
    """LAPACK-style storage ab[j, kl + ku + i - j] = A[i, j]; the first kl entries hold ``fill``."""
    n = A.shape[0]
    ab = band_storage(n, kl, ku)
    ab[:, :kl] = fill
    for j in range(n):
        for i in range(max(0, j - ku), min(n, j + kl + 1)):
            ab[j, kl + ku + i - j] = A[i, j]
    return ab


def factor_and_solve(A, kl, ku, b, fill=0.0):
    ab = to_band(A, kl, ku, fill)
    ipiv = np.zeros(A.shape[0], dtype=np.int64)
    info = band_lu(ab, kl, ku, ipiv)
    x = b.copy()
    band_solve(ab, kl, ku, ipiv, x)
    return info, x, ab, ipiv


SHAPES = [
    (1, 0, 0),     # 1 x 1
    (2, 1, 1),     # full 2 x 2
    (6, 5, 5),     # full dense
    (7, 6, 2),     # full lower part, partial upper
    (9, 0, 0),     # diagonal
    (10, 0, 3),    # upper triangular band (no pivoting possible)
    (10, 2, 0),    # lower triangular band
    (12, 1, 1),    # tridiagonal
    (25, 3, 2),
    (40, 2, 5),
    (60, 7, 7),
]


@pytest.mark.parametrize("n, kl, ku", SHAPES)
def test_band_storage_shape(n, kl, ku):
    ab = band_storage(n, kl, ku)
    assert ab.shape == (n, 2 * kl + ku + 1)
    assert not ab.any()


@pytest.mark.parametrize("n, kl, ku", SHAPES)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_band_solve_matches_numpy(n, kl, ku, seed):
    rng = np.random.default_rng(seed)
    A = random_banded(rng, n, kl, ku)
    b = rng.standard_normal(n)
    info, x, _, _ = factor_and_solve(A, kl, ku, b)
    assert info == 0
    expected = np.linalg.solve(A, b)
    np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-11 * np.abs(expected).max())
    np.testing.assert_allclose(A @ x, b, rtol=0, atol=1e-10 * (1 + np.abs(b).max()))


@pytest.mark.parametrize("n, kl, ku", SHAPES)
def test_complex_band_solve_matches_numpy(n, kl, ku):
    """The same code factors complex matrices (I - k lambda J for complex lambda)."""
    rng = np.random.default_rng(n)
    A = random_banded(rng, n, kl, ku) + 1j * random_banded(rng, n, kl, ku)
    b = rng.standard_normal(n) + 1j * rng.standard_normal(n)
    ab = to_band(A.real, kl, ku) + 1j * to_band(A.imag, kl, ku)
    ipiv = np.zeros(n, dtype=np.int64)
    assert band_lu(ab, kl, ku, ipiv) == 0
    x = b.copy()
    band_solve(ab, kl, ku, ipiv, x)
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-9,
                               atol=1e-11 * np.abs(x).max())


@pytest.mark.parametrize("n, kl, ku", [(2, 1, 1), (6, 1, 1), (8, 2, 1), (12, 1, 3), (30, 3, 3),
                                       (6, 5, 5)])
def test_zero_diagonal_needs_pivoting(n, kl, ku):
    rng = np.random.default_rng(n + kl + ku)
    A = random_banded(rng, n, kl, ku, zero_diagonal=True)
    # nonsingular (a zero-diagonal tridiagonal matrix must have even size), but without an LU
    # factorisation unless rows are interchanged
    assert np.linalg.cond(A) < 1e8
    b = rng.standard_normal(n)
    info, x, _, ipiv = factor_and_solve(A, kl, ku, b)
    assert info == 0
    assert ipiv[0] != 0  # the zero pivot A[0, 0] was swapped
    assert np.all(ipiv >= np.arange(n)) and np.all(ipiv <= np.minimum(np.arange(n) + kl, n - 1))
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-8, atol=1e-10)


def test_permutation_matrix():
    """Anti-diagonal 2 x 2 blocks: every step must interchange rows."""
    A = np.zeros((6, 6))
    for j in range(0, 6, 2):
        A[j, j + 1] = 2.0
        A[j + 1, j] = -3.0
    b = np.arange(1.0, 7.0)
    info, x, _, ipiv = factor_and_solve(A, 1, 1, b)
    assert info == 0
    np.testing.assert_array_equal(ipiv[::2], [1, 3, 5])
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-15)


def test_fill_in_storage_need_not_be_zeroed():
    """band_lu clears the kl fill-in entries itself, so leftovers of a previous use are harmless."""
    rng = np.random.default_rng(7)
    n, kl, ku = 15, 2, 3
    A = random_banded(rng, n, kl, ku, zero_diagonal=True)
    b = rng.standard_normal(n)
    _, x_clean, _, _ = factor_and_solve(A, kl, ku, b, fill=0.0)
    _, x_dirty, _, _ = factor_and_solve(A, kl, ku, b, fill=np.nan)
    np.testing.assert_array_equal(x_dirty, x_clean)
    np.testing.assert_allclose(x_clean, np.linalg.solve(A, b), rtol=1e-8, atol=1e-10)


def test_factors_are_reused_for_several_right_hand_sides():
    rng = np.random.default_rng(3)
    n, kl, ku = 20, 2, 2
    A = random_banded(rng, n, kl, ku)
    ab = to_band(A, kl, ku)
    ipiv = np.zeros(n, dtype=np.int64)
    assert band_lu(ab, kl, ku, ipiv) == 0
    B = rng.standard_normal((n, 4))
    for col in range(4):
        x = B[:, col].copy()
        band_solve(ab, kl, ku, ipiv, x)
        np.testing.assert_allclose(A @ x, B[:, col], atol=1e-11)


@pytest.mark.parametrize("column", [0, 3, 9])
def test_singular_matrix_reports_the_zero_pivot(column):
    rng = np.random.default_rng(column)
    n, kl, ku = 10, 2, 2
    A = random_banded(rng, n, kl, ku)
    A[:, column] = 0.0  # column of zeros: U[column, column] = 0 whatever the pivoting
    ab = to_band(A, kl, ku)
    ipiv = np.zeros(n, dtype=np.int64)
    assert band_lu(ab, kl, ku, ipiv) == column + 1


# --- bandwidth ordering -----------------------------------------------------------------------


def csr_pattern(dense_mask):
    pattern = sps.csr_matrix(dense_mask.astype(float))
    pattern.sort_indices()
    return pattern.indptr.astype(np.int64), pattern.indices.astype(np.int64)


def bandwidths(indptr, indices, position):
    """Lower and upper bandwidths of the pattern with component i moved to position[i]."""
    n = len(indptr) - 1
    rows = np.repeat(np.arange(n), np.diff(indptr))
    offset = position[rows] - position[indices]
    return int(max(offset.max(initial=0), 0)), int(max(-offset.min(initial=0), 0))


def check_ordering(indptr, indices, n):
    order, position, kl, ku = bandwidth_ordering(indptr, indices, n)
    assert sorted(order) == list(range(n))
    np.testing.assert_array_equal(position[order], np.arange(n))
    assert (kl, ku) == bandwidths(indptr, indices, position)
    return order, position, kl, ku


@pytest.mark.parametrize("seed", range(5))
def test_permuted_tridiagonal_pattern_recovers_bandwidth_one(seed):
    n = 40
    rng = np.random.default_rng(seed)
    i, j = np.indices((n, n))
    tridiagonal = np.abs(i - j) <= 1
    perm = rng.permutation(n)
    scrambled = tridiagonal[np.ix_(perm, perm)]
    indptr, indices = csr_pattern(scrambled)
    assert sum(bandwidths(indptr, indices, np.arange(n))) > 10  # the scramble is really wide
    _, _, kl, ku = check_ordering(indptr, indices, n)
    assert (kl, ku) == (1, 1)


def test_natural_order_is_kept_when_already_narrow():
    n = 12
    i, j = np.indices((n, n))
    indptr, indices = csr_pattern(np.abs(i - j) <= 2)
    order, _, kl, ku = check_ordering(indptr, indices, n)
    assert (kl, ku) == (2, 2)
    np.testing.assert_array_equal(order, np.arange(n))


def test_one_sided_chain():
    """f_i depends on u_i and u_{i-1}: a band of total width one, on whichever side."""
    n = 30
    i, j = np.indices((n, n))
    perm = np.random.default_rng(11).permutation(n)
    mask = ((i == j) | (i == j + 1))[np.ix_(perm, perm)]
    indptr, indices = csr_pattern(mask)
    _, _, kl, ku = check_ordering(indptr, indices, n)
    assert kl + ku == 1


@pytest.mark.parametrize("n", [1, 2, 5])
def test_diagonal_and_empty_patterns(n):
    indptr, indices = csr_pattern(np.eye(n, dtype=bool))
    assert check_ordering(indptr, indices, n)[2:] == (0, 0)
    indptr, indices = np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    assert check_ordering(indptr, indices, n)[2:] == (0, 0)


def dominant_banded(rng, n, kl, ku, dtype=float):
    """Banded matrix whose diagonal entry is the largest of its column (no row interchanges),
    as the Newton matrices I - c J of diffusion problems."""
    A = random_banded(rng, n, kl, ku)
    if dtype is complex:
        A = A + 1j * random_banded(rng, n, kl, ku)
    A[np.diag_indices(n)] = (kl + ku + 2.0) * (1.0 + 0.5j if dtype is complex else 1.0)
    return A


def band_of(A, kl, ku):
    return to_band(A.real, kl, ku) + 1j * to_band(A.imag, kl, ku) if A.dtype.kind == "c" \
        else to_band(A, kl, ku)


@pytest.mark.parametrize("dtype", [float, complex])
@pytest.mark.parametrize("n, kl, ku", [(1, 0, 0), (2, 1, 1), (3, 2, 2), (9, 0, 2), (9, 2, 0),
                                       (10, 1, 1), (31, 2, 2), (31, 1, 2), (31, 2, 1)])
def test_narrow_band_without_interchanges(n, kl, ku, dtype):
    """kl, ku <= NARROW without row interchanges: the unrolled factorization and the solve by
    rows (registers carrying the unknowns) agree with numpy, and no row was interchanged."""
    rng = np.random.default_rng(10 * n + kl + ku)
    A = dominant_banded(rng, n, kl, ku, dtype)
    b = rng.standard_normal(n).astype(dtype)
    ab = band_of(A, kl, ku)
    ipiv = np.full(n, -1, dtype=np.int64)
    assert band_lu(ab, kl, ku, ipiv) == 0
    np.testing.assert_array_equal(ipiv, np.arange(n))
    x = b.copy()
    band_solve(ab, kl, ku, ipiv, x)
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("dtype", [float, complex])
@pytest.mark.parametrize("kl, ku", [(1, 1), (2, 2), (2, 1)])
def test_narrow_band_hands_over_at_an_interchange(kl, ku, dtype):
    """A column whose largest entry is below the diagonal, midway: the unrolled columns stop
    there and partial pivoting takes over (the interchange is made, as LAPACK's gbtrf would),
    and the solve, now with interchanges, still matches numpy."""
    n, j = 20, 11
    rng = np.random.default_rng(kl + 3 * ku)
    A = dominant_banded(rng, n, kl, ku, dtype)
    A[j, j] = 0.1  # the sub-diagonal entries of column j are O(1)
    A[j + 1, j] = 3.0
    b = rng.standard_normal(n).astype(dtype)
    ab = band_of(A, kl, ku)
    ipiv = np.zeros(n, dtype=np.int64)
    assert band_lu(ab, kl, ku, ipiv) == 0
    assert ipiv[j] != j
    np.testing.assert_array_equal(ipiv[:j], np.arange(j))
    x = b.copy()
    band_solve(ab, kl, ku, ipiv, x)
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-11, atol=1e-13)


def test_narrow_band_singular_reports_the_column():
    """A zero column midway stops the unrolled columns; the general loop reports it (info)."""
    n, kl, ku = 12, 2, 2
    A = dominant_banded(np.random.default_rng(5), n, kl, ku)
    A[:, 6] = 0.0
    ab = to_band(A, kl, ku)
    assert band_lu(ab, kl, ku, np.zeros(n, dtype=np.int64)) == 7
