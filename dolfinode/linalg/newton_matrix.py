"""The N x N Newton matrices I - c J of the stage systems, in banded or sparse storage.

Which storage a solve uses is decided from the sparsity pattern and the method
(:func:`newton_structure`), by the estimated time of the factorizations and of the solves
that follow them; the compiled loops see one ``structure`` tuple and the functions below,
whichever it is:

``structure = (position, kl, ku, ptr, idx, diag, jmap)``: ``position[i]`` is the place of
component i in the matrices' ordering. Banded (:mod:`dolfinode.linalg.banded`): the bandwidths
kl, ku in the reverse Cuthill-McKee ordering, the other arrays empty, storage (N, 2 kl + ku + 1).
Sparse (:mod:`dolfinode.linalg.sparse`): the filled pattern (ptr, idx, diag) in the minimum
degree ordering, storage one row of its nnz values, ``jmap[nz]`` the place of J's CSR entry nz
in it; kl = ku = 0.
"""
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sps
from numba import types

from dolfinode.compile.jit import helper, linked
from dolfinode.compile.signatures import NO_REFCOUNT
from dolfinode.linalg.banded import band_lu, band_solve
from dolfinode.linalg.sparse import (
    fill_reducing_ordering,
    lu_flops,
    sparse_lu,
    sparse_solve,
    symbolic_lu,
)

#: Seconds per multiply-add of the LUs and per stored entry read by their solves, for real and
#: complex values (fitted on 2-D Brusselator and 3-D Laplacian patterns, N = 72-7200): the
#: banded LU is vectorized (a real multiply-add 0.15-0.2 ns, a complex one
#: 0.65 ns), the sparse one reads every entry through an index (2 and 3.5 ns). A sparse
#: factorization also scatters and gathers every entry of its rows.
SECONDS = {("banded", False): (0.17e-9, 0.45e-9), ("banded", True): (0.65e-9, 2.5e-9),
           ("sparse", False): (2.0e-9, 1.9e-9), ("sparse", True): (3.5e-9, 3.0e-9)}
SPARSE_SCATTER = 2.0e-9
#: Solves per factorization in the choice: a Newton slab makes 3-5 iterations; kept factors
#: (see :data:`dolfinode.timeslab.mono.REUSE_TIME`) see more, which only favours the sparse LU.
SOLVES_PER_FACTORIZATION = 4
#: The sparse LU must be estimated this much faster to be chosen, and only systems with at
#: least SPARSE_MIN_N components and bandwidths kl + ku >= SPARSE_MIN_BAND are analysed, when
#: a solve first needs Newton's method (below these, the banded LU is as fast or faster, and
#: the analysis would not pay). The analysis is made once per pattern and method, so small
#: systems qualify: on POLLU (N = 20, band 15 + 15 after reordering, 82 nonzeros) a sparse
#: complex LU takes 1.6 us against the band's 2.6 us, a solve 0.46 us against 0.86 us.
SPARSE_MARGIN = 0.8
SPARSE_MIN_N = 20
SPARSE_MIN_BAND = 16


@dataclass(frozen=True)
class NewtonStructure:
    """Storage of the Newton matrices of one sparsity pattern (see the module docstring), with
    the multiply-adds of one factorization (``flops``) and the entries a solve reads."""

    position: np.ndarray
    kl: int
    ku: int
    ptr: np.ndarray
    idx: np.ndarray
    diag: np.ndarray
    jmap: np.ndarray
    flops: int
    entries: int

    @property
    def sparse(self):
        return len(self.ptr) > 0

    @property
    def shape(self):
        """Shape of one matrix's storage."""
        if self.sparse:
            return (1, len(self.idx))
        return (len(self.position), 2 * self.kl + self.ku + 1)

    @property
    def tuple(self):
        """What the compiled loops take."""
        return (self.position, self.kl, self.ku, self.ptr, self.idx, self.diag, self.jmap)

    @property
    def description(self):
        """How the matrices are stored, for statistics and messages."""
        if self.sparse:
            return f"sparse LU, {len(self.idx)} nonzeros in the factors"
        return f"banded LU, bandwidth {self.kl} + {self.ku} after reordering"

    def factor_seconds(self, complex_values):
        """Estimated time of one factorization (see SECONDS)."""
        flop = SECONDS["sparse" if self.sparse else "banded", complex_values][0]
        return flop * self.flops + (SPARSE_SCATTER * self.entries if self.sparse else 0.0)

    def solve_seconds(self, complex_values):
        """Estimated time of one solve (see SECONDS)."""
        return SECONDS["sparse" if self.sparse else "banded", complex_values][1] * self.entries

    def seconds(self, complex_values, solves=0):
        """Estimated time of one factorization and ``solves`` solves."""
        return (self.factor_seconds(complex_values)
                + solves * self.solve_seconds(complex_values))

    def memory(self, stages):
        """Bytes of the Newton workspace of a method with S stages (q for cG(q), q + 1 for
        dG(q)), an upper bound: the matrices I - k lambda J, one real per real eigenvalue
        lambda of the stage matrix and one complex (16 bytes an entry) per complex pair (so
        at most S real ones' worth), and J, which then holds the error filter
        (I - gamma k J)^{-1}; at most S + 1 pivot vectors and S + 3 work vectors of N entries.
        Banded: ``8 (S + 1) N (2 kl + ku + 4)``. Allocated only when a solve uses Newton's
        method (``nonlinear_solver="newton"``, or the default once fixed-point iteration
        fails)."""
        rows, columns = self.shape
        return 8 * (stages + 1) * (rows * columns + 3 * len(self.position))


def band_structure(position, kl, ku):
    """The banded :class:`NewtonStructure` in the ordering ``position``."""
    N = len(position)
    empty = np.zeros(0, dtype=np.int64)
    return NewtonStructure(position, kl, ku, empty, empty, empty, empty,
                           N * kl * (kl + ku + 1), N * (2 * kl + ku + 1))


def sparse_structure(indptr, indices, n):
    """The sparse :class:`NewtonStructure` of the pattern (indptr, indices) (CSR, n x n)."""
    position = fill_reducing_ordering(indptr, indices, n)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    permuted = sps.csr_matrix((np.ones(len(indices)), (position[rows], position[indices])),
                              shape=(n, n))
    symmetric = (permuted + permuted.T + sps.identity(n)).tocsr()
    symmetric.sort_indices()
    ptr, idx, diag = symbolic_lu(symmetric.indptr.astype(np.int64),
                                 symmetric.indices.astype(np.int64), n)
    # place of J's entry (i, j) at (position[i], position[j]): the filled entries' keys
    # row n + column increase along the storage (rows in order, idx sorted within each)
    filled_keys = np.repeat(np.arange(n), np.diff(ptr)) * n + idx
    jmap = np.searchsorted(filled_keys, position[rows] * n + position[indices])
    return NewtonStructure(position, 0, 0, ptr, idx, diag, jmap, lu_flops(ptr, idx, diag),
                           len(idx))


def sparse_candidate(band):
    """Whether a sparse LU may beat the banded :class:`NewtonStructure` ``band``: at least
    SPARSE_MIN_N components and kl + ku >= SPARSE_MIN_BAND (its analysis, a minimum degree
    ordering and the filled pattern, is only made then)."""
    return len(band.position) >= SPARSE_MIN_N and band.kl + band.ku >= SPARSE_MIN_BAND


def newton_structure(band, make_sparse, eigenvalues):
    """The storage for a method whose stage matrix has ``eigenvalues``: ``band``, or the
    sparse structure ``make_sparse()`` when one factorization and SOLVES_PER_FACTORIZATION
    solves are estimated SPARSE_MARGIN times faster (wide bands: 2-D and 3-D couplings), in
    complex arithmetic if the method has a complex pair (its complex matrices dominate the
    cost), else in real, where the vectorized band holds out to larger systems (whole
    solves with Newton confirm the choice on 2-D wave and Brusselator systems)."""
    if not sparse_candidate(band):
        return band
    sparse = make_sparse()
    complex_values = bool(np.any(np.imag(eigenvalues) != 0))

    def cost(s):
        return s.seconds(complex_values, SOLVES_PER_FACTORIZATION)

    return sparse if cost(sparse) < SPARSE_MARGIN * cost(band) else band


@linked(returns=types.none, what="the Newton matrices' storage", seconds=1)
@helper(**NO_REFCOUNT)
def store_jacobian(jdata, indptr, indices, structure, jb):
    """J (its CSR values ``jdata``) into the storage ``jb``: scattered once per Jacobian,
    then shifted by :func:`shift` into each matrix I - c J the slab needs."""
    position, kl, ku, ptr, _, _, jmap = structure
    jb[:, :] = 0.0
    if ptr.shape[0] > 0:
        for nz in range(jdata.shape[0]):
            jb[0, jmap[nz]] = jdata[nz]
        return
    kv = kl + ku
    for i in range(position.shape[0]):
        r = position[i]
        for nz in range(indptr[i], indptr[i + 1]):
            col = position[indices[nz]]
            jb[col, kv + r - col] += jdata[nz]


@linked(returns=types.none, what="the Newton matrices' shift", seconds=1)
@helper(**NO_REFCOUNT)
def shift(jb, c, structure, ab):
    """ab = I - c J (c real or complex) from J in the storage ``jb`` (ab may be jb); the band
    storage's kl fill-in columns are band_lu's to clear."""
    _, kl, ku, ptr, _, diag, _ = structure
    if ptr.shape[0] > 0:
        for e in range(jb.shape[1]):
            ab[0, e] = -c * jb[0, e]
        for r in range(diag.shape[0]):
            ab[0, diag[r]] += 1.0
        return
    kv = kl + ku
    for r in range(jb.shape[0]):
        for col in range(kl, jb.shape[1]):
            ab[r, col] = -c * jb[r, col]
        ab[r, kv] += 1.0


@linked
@helper(**NO_REFCOUNT)
def lu_factor(ab, structure, ipiv):
    """LU-factor I - c J in place (pivots into ``ipiv``, banded only). Returns 0 on
    success."""
    _, kl, ku, ptr, idx, diag, _ = structure
    if ptr.shape[0] > 0:
        return sparse_lu(ab[0], ptr, idx, diag)
    return band_lu(ab, kl, ku, ipiv)


@helper(**NO_REFCOUNT)
def lu_solve(ab, structure, ipiv, b):
    """Solve (I - c J) x = b in place, b in the matrices' ordering, with the factors of
    :func:`lu_factor`."""
    _, kl, ku, ptr, idx, diag, _ = structure
    if ptr.shape[0] > 0:
        sparse_solve(ab[0], ptr, idx, diag, b)
    else:
        band_solve(ab, kl, ku, ipiv, b)
