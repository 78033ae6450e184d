"""Recursive construction of multi-adaptive time slabs."""
import numpy as np
import pytest

from dolfinode.timeslab.partition import build_slab, one_group_end


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


def test_one_group_end_is_build_slabs_end_when_it_makes_one_group():
    """On random desired steps, thresholds, slab limits and start times (steps beyond T - a
    included): one_group_end is NaN exactly when build_slab makes more than one sub-slab,
    and otherwise build_slab's end, bitwise."""
    rng = np.random.default_rng(7)
    comp, ea, eb, windows = np.empty(1, np.int64), np.empty(1), np.empty(1), np.empty(1, np.int64)
    ones = 0
    for _ in range(400):
        n = int(rng.integers(1, 6))
        kdes = 10.0 ** rng.uniform(-2, 0.3, n)
        if rng.random() < 0.3:  # (nearly shared steps)
            kdes[:] = kdes[0] * rng.uniform(0.8, 1.0, n)
        a, T = rng.uniform(0, 1), 2.0
        theta, beta = rng.choice([0.0, 0.5, 0.99]), rng.choice([0.5, 0.9])
        kslab = rng.choice([np.inf, rng.uniform(0.01, 1.0)])
        b, _, nsub, _, comp, ea, eb, windows = build_slab(a, T, kdes, np.arange(n), theta, beta,
                                                           kslab, comp, ea, eb, windows)
        kmin = np.minimum(kdes, T - a).min()
        end = one_group_end(a, T, kdes.max(), kmin, theta, beta, kslab)
        if nsub == 1:
            ones += 1
            assert end == b
        else:
            assert np.isnan(end)
    assert 50 < ones < 400

