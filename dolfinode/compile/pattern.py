"""Sparse pattern of a sum of local Jacobians assembled over index arrays, in O(entries).

Every template cell e contributes local entries (I[e, row_k], I[e, col_k]), k < K, to df/du.
The global CSR pattern is their union, and each local entry needs its position in the CSR
values (where the Jacobian kernel adds it). A global sort of the M = sum_T E_T K_T entry
keys followed by a binary search per entry costs O(M log M) with cache-hostile lookups
(1 s of the 1.1 s lowering of the p = 300 lattice, M = 6 10^6); here the entries are
bucketed by row (a counting sort, O(M)) and each short row is sorted and merged on its own.
"""
import numpy as np
from numba import njit


@njit(cache=True)
def _count_rows(index, rows, counts):
    for e in range(index.shape[0]):
        for k in range(rows.shape[0]):
            counts[index[e, rows[k]]] += 1


@njit(cache=True)
def _bucket(index, rows, columns, first_entry, fill, column, source):
    """Append the column and the entry number of every local entry to its row's bucket."""
    entries = rows.shape[0]
    for e in range(index.shape[0]):
        for k in range(entries):
            r = index[e, rows[k]]
            slot = fill[r]
            fill[r] = slot + 1
            column[slot] = index[e, columns[k]]
            source[slot] = first_entry + e * entries + k


@njit(cache=True)
def _sort_row(column, source, lo, hi):
    """Sort column[lo:hi] ascending, carrying source along: Shell sort (Ciura's gaps), an
    insertion sort for the usual short rows that stays subquadratic on a hub's long row."""
    for gap in (701, 301, 132, 57, 23, 10, 4, 1):
        for a in range(lo + gap, hi):
            c, s = column[a], source[a]
            b = a
            while b - gap >= lo and column[b - gap] > c:
                column[b] = column[b - gap]
                source[b] = source[b - gap]
                b -= gap
            column[b] = c
            source[b] = s


@njit(cache=True)
def _merge_rows(start, column, source, indptr, position):
    """Sort every row bucket, merge repeated columns and compact the unique ones to the
    front of ``column``; position[entry] = the CSR position of that entry. Returns nnz."""
    nnz = 0
    for i in range(start.shape[0] - 1):
        lo, hi = start[i], start[i + 1]
        _sort_row(column, source, lo, hi)
        last = -1
        for a in range(lo, hi):
            c = column[a]
            if c != last:
                column[nnz] = c  # nnz <= a: only already-read slots are overwritten
                nnz += 1
                last = c
            position[source[a]] = nnz - 1
        indptr[i + 1] = nnz
    return nnz


def assemble_pattern(n, blocks):
    """CSR pattern of the union of local entries, and every entry's CSR position.

    Parameters
    ----------
    n : int
        Number of rows and columns.
    blocks : sequence of (index, rows, columns)
        ``index`` (E, S) int64: the global component of each slot of each cell; ``rows`` and
        ``columns`` (K,) int64: the slots of the K local entries of one cell.

    Returns
    -------
    indptr (n + 1,), indices (nnz,) : int64 CSR pattern, columns sorted within each row
    positions : list of (E, K) int64 arrays, one per block: CSR position of each entry
    """
    blocks = [(np.ascontiguousarray(index, dtype=np.int64), np.asarray(rows, dtype=np.int64),
               np.asarray(columns, dtype=np.int64)) for index, rows, columns in blocks]
    sizes = [len(index) * len(rows) for index, rows, _ in blocks]
    first = np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]).astype(np.int64)
    counts = np.zeros(n, dtype=np.int64)
    for index, rows, _ in blocks:
        if len(index) and len(rows):
            _count_rows(index, rows, counts)
    start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=start[1:])
    fill = start[:-1].copy()
    total = int(first[-1])
    column = np.empty(total, dtype=np.int64)
    source = np.empty(total, dtype=np.int64)
    for (index, rows, columns), offset in zip(blocks, first):
        if len(index) and len(rows):
            _bucket(index, rows, columns, offset, fill, column, source)
    indptr = np.zeros(n + 1, dtype=np.int64)
    position = np.empty(total, dtype=np.int64)
    nnz = _merge_rows(start, column, source, indptr, position)
    indices = column[:nnz].copy()
    positions = [position[lo:hi].reshape(len(index), len(rows))
                 for (index, rows, _), lo, hi in zip(blocks, first[:-1], first[1:])]
    return indptr, indices, positions
