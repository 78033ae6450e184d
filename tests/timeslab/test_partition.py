"""Recursive construction of multi-adaptive time slabs."""
import numpy as np
import pytest

from dolfinode.timeslab.partition import build_slab


def test_slab_structure():
    """Recursive construction: groups by threshold, slab ends synchronised."""
    kdes = np.array([0.1, 0.05, 0.1, 0.0125])
    comp, ea, eb = np.empty(1, np.int64), np.empty(1), np.empty(1)
    b, ne, _, _, comp, ea, eb, _ = build_slab(0.0, 10.0, kdes, np.arange(4), 0.99, 0.9, np.inf,
                                              comp, ea, eb, np.empty(1, np.int64))
    assert b == pytest.approx(0.1)
    counts = np.bincount(comp[:ne], minlength=4)
    np.testing.assert_array_equal(counts, [1, 2, 1, 8])
    for i in range(4):
        mine = np.flatnonzero(comp[:ne] == i)
        assert ea[mine[0]] == 0.0 and eb[mine[-1]] == pytest.approx(0.1)
        np.testing.assert_allclose(ea[mine[1:]], eb[mine[:-1]])


def test_top_level_group_is_capped_by_the_slab_length():
    """Every component whose desired step reaches theta times the slab length limit joins the
    top level (one element over the whole slab), however large the largest desired step."""
    kdes = np.array([1.0, 0.003, 0.0018, 0.0004])
    comp, ea, eb = np.empty(1, np.int64), np.empty(1), np.empty(1)
    b, ne, _, _, comp, ea, eb, _ = build_slab(0.0, 10.0, kdes, np.arange(4), 0.5, 0.9, 0.002,
                                              comp, ea, eb, np.empty(1, np.int64))
    counts = np.bincount(comp[:ne], minlength=4)
    assert b == pytest.approx(0.0018)  # the top group's smallest step, within the limit
    np.testing.assert_array_equal(counts[:3], [1, 1, 1])
    assert counts[3] == 5  # 0.0018 / 0.0004 = 4.5: four elements and a short last one


def test_frozen_components_get_no_element():
    """Only the active components are partitioned; the slab is built from their steps."""
    kdes = np.array([0.1, 1e-3, 0.05, 0.1])
    comp, ea, eb = np.empty(1, np.int64), np.empty(1), np.empty(1)
    b, ne, _, _, comp, ea, eb, _ = build_slab(0.0, 10.0, kdes, np.array([0, 2, 3]), 0.99, 0.9,
                                              np.inf, comp, ea, eb, np.empty(1, np.int64))
    assert b == pytest.approx(0.1)
    np.testing.assert_array_equal(np.bincount(comp[:ne], minlength=4), [1, 0, 2, 1])
