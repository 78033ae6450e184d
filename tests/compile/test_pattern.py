"""The O(entries) CSR pattern assembly against np.unique + searchsorted."""
import numpy as np
import pytest

from dolfinode.compile.pattern import assemble_pattern


def reference(n, blocks):
    keys = [index[:, rows] * n + index[:, columns] for index, rows, columns in blocks]
    unique = np.unique(np.concatenate([k.ravel() for k in keys]))
    indptr = np.concatenate([[0], np.cumsum(np.bincount(unique // n, minlength=n))])
    return indptr, unique % n, [np.searchsorted(unique, k) for k in keys]


def random_blocks(n, seed):
    rng = np.random.default_rng(seed)
    blocks = []
    for cells, slots, entries in ((50, 2, 3), (200, 4, 9), (0, 3, 2), (7, 1, 1)):
        index = rng.integers(0, n, size=(cells, slots))
        blocks.append((index, rng.integers(0, slots, entries), rng.integers(0, slots, entries)))
    # a hub: component 0 joined to every other one, so row 0 has ~2000 entries (Shell sort)
    spokes = np.column_stack([np.zeros(n - 1, dtype=np.int64), np.arange(1, n)])
    blocks.append((np.vstack([spokes, spokes]), np.array([0, 0, 1]), np.array([1, 0, 0])))
    return blocks


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pattern_and_positions_equal_unique_and_searchsorted(seed):
    n = 1000
    blocks = random_blocks(n, seed)
    indptr, indices, positions = assemble_pattern(n, blocks)
    expected_indptr, expected_indices, expected_positions = reference(n, blocks)
    np.testing.assert_array_equal(indptr, expected_indptr)
    np.testing.assert_array_equal(indices, expected_indices)
    for got, expected, (index, rows, _) in zip(positions, expected_positions, blocks):
        assert got.shape == (len(index), len(rows)) and got.flags.c_contiguous
        np.testing.assert_array_equal(got, expected)


def test_empty_pattern():
    indptr, indices, positions = assemble_pattern(3, [(np.zeros((0, 2), dtype=np.int64),
                                                       [0], [1])])
    np.testing.assert_array_equal(indptr, [0, 0, 0, 0])
    assert indices.size == 0 and positions[0].shape == (0, 1)
