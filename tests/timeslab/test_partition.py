"""Recursive construction of multi-adaptive time slabs."""
import numpy as np
import pytest

from dolfinode.timeslab.partition import build_slab


def test_slab_structure():
    """Recursive construction: groups by threshold, slab ends synchronised."""
    kdes = np.array([0.1, 0.05, 0.1, 0.0125])
    comp, ea, eb = np.empty(1, np.int64), np.empty(1), np.empty(1)
    b, ne, _, _, comp, ea, eb, _ = build_slab(0.0, 10.0, kdes, 0.99, 0.9, np.inf, comp, ea,
                                                          eb, np.empty(1, np.int64))
    assert b == pytest.approx(0.1)
    counts = np.bincount(comp[:ne], minlength=4)
    np.testing.assert_array_equal(counts, [1, 2, 1, 8])
    for i in range(4):
        mine = np.flatnonzero(comp[:ne] == i)
        assert ea[mine[0]] == 0.0 and eb[mine[-1]] == pytest.approx(0.1)
        np.testing.assert_allclose(ea[mine[1:]], eb[mine[:-1]])
