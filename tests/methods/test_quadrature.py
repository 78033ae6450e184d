"""Gauss-Lobatto and right Gauss-Radau rules on [0, 1]: nodes, weights and degree of exactness.

The rules are computed in mpmath at 60 digits, so exactness is checked in that precision
(and again after rounding to double). The error of the first polynomial degree that is not
integrated exactly is compared with its closed form: for n = 12 Lobatto points it is about
1e-13 (3.7e-13 for 11 Radau points), below any fixed threshold like 1e-12 in double precision.
"""
import itertools
import math

import mpmath as mp
import numpy as np
import pytest

from dolfinode.methods.quadrature import _DPS, lobatto, radau

LOBATTO_POINTS = range(2, 13)   # cG(q) uses q + 1 points: q = 1..11
RADAU_POINTS = range(1, 13)     # dG(q) uses q + 1 points: q = 0..11
TINY = mp.mpf(10) ** (-50)


@pytest.fixture(autouse=True)
def high_precision():
    """Every mpmath operation in these tests (abs, comparisons) at the rules' 60 digits."""
    with mp.workdps(_DPS):
        yield


def quadrature_error(rule, degree):
    """sum_m w_m x_m^d - int_0^1 t^d dt, in the rule's precision."""
    nodes, weights = rule
    return mp.fsum(w * x**degree for x, w in zip(nodes, weights)) - mp.mpf(1) / (degree + 1)


def lobatto_error_constant(n):
    """|error| of the n-point Lobatto rule for t^(2n-2) on [0, 1]:
    n (n-1)^3 ((n-2)!)^4 / ((2n-1) ((2n-2)!)^2) (Abramowitz & Stegun 25.4.32, mapped to [0, 1])."""
    f = mp.factorial
    return n * (n - 1) ** 3 * f(n - 2) ** 4 / ((2 * n - 1) * f(2 * n - 2) ** 2)


def radau_error_constant(n):
    """|error| of the n-point Radau rule for t^(2n-1) on [0, 1]:
    n ((n-1)!)^4 / (2 ((2n-1)!)^2) (A & S 25.4.31, mapped to [0, 1])."""
    f = mp.factorial
    return n * f(n - 1) ** 4 / (2 * f(2 * n - 1) ** 2)


@pytest.mark.parametrize("n", LOBATTO_POINTS)
def test_lobatto_is_exact_up_to_degree_2n_minus_3(n):
    rule = lobatto(n)
    for degree in range(2 * n - 2):
        assert abs(quadrature_error(rule, degree)) < TINY, degree
    nodes = np.array([float(x) for x in rule[0]])
    weights = np.array([float(w) for w in rule[1]])
    for degree in range(2 * n - 2):
        assert weights @ nodes**degree == pytest.approx(1 / (degree + 1), rel=1e-14, abs=0)


@pytest.mark.parametrize("n", LOBATTO_POINTS)
def test_lobatto_is_not_exact_for_degree_2n_minus_2(n):
    error = abs(quadrature_error(lobatto(n), 2 * n - 2))
    assert error > mp.mpf(10) ** (-30)
    assert mp.almosteq(error, lobatto_error_constant(n), rel_eps=mp.mpf(10) ** (-40))


@pytest.mark.parametrize("n", RADAU_POINTS)
def test_radau_is_exact_up_to_degree_2n_minus_2(n):
    rule = radau(n)
    for degree in range(2 * n - 1):
        assert abs(quadrature_error(rule, degree)) < TINY, degree
    nodes = np.array([float(x) for x in rule[0]])
    weights = np.array([float(w) for w in rule[1]])
    for degree in range(2 * n - 1):
        assert weights @ nodes**degree == pytest.approx(1 / (degree + 1), rel=1e-14, abs=0)


@pytest.mark.parametrize("n", RADAU_POINTS)
def test_radau_is_not_exact_for_degree_2n_minus_1(n):
    error = abs(quadrature_error(radau(n), 2 * n - 1))
    assert error > mp.mpf(10) ** (-30)
    assert mp.almosteq(error, radau_error_constant(n), rel_eps=mp.mpf(10) ** (-40))


@pytest.mark.parametrize("rule, n", [(lobatto, n) for n in LOBATTO_POINTS]
                         + [(radau, n) for n in RADAU_POINTS])
def test_nodes_sorted_in_unit_interval_and_weights_positive_summing_to_one(rule, n):
    nodes, weights = rule(n)
    assert len(nodes) == len(weights) == n
    assert all(0 <= x <= 1 for x in nodes)
    assert all(a < b for a, b in itertools.pairwise(nodes))
    assert all(w > 0 for w in weights)
    assert abs(mp.fsum(weights) - 1) < TINY


@pytest.mark.parametrize("n", LOBATTO_POINTS)
def test_lobatto_includes_both_end_points_and_is_symmetric(n):
    nodes, weights = lobatto(n)
    assert nodes[0] == 0 and nodes[-1] == 1
    for i in range(n):
        assert abs(nodes[i] + nodes[n - 1 - i] - 1) < TINY
        assert abs(weights[i] - weights[n - 1 - i]) < TINY
    # end-point weights of Lobatto on [0, 1]: 1 / (n (n - 1))
    assert abs(weights[0] - mp.mpf(1) / (n * (n - 1))) < TINY


@pytest.mark.parametrize("n", RADAU_POINTS)
def test_radau_includes_one_but_not_zero(n):
    nodes, weights = radau(n)
    assert nodes[-1] == 1
    assert nodes[0] > 0
    # the weight at t = 1 of the right Radau rule on [0, 1] is 1 / n^2
    assert abs(weights[-1] - mp.mpf(1) / n**2) < TINY


def test_known_small_rules():
    nodes, weights = lobatto(3)   # Simpson's rule
    assert [float(x) for x in nodes] == [0.0, 0.5, 1.0]
    np.testing.assert_allclose([float(w) for w in weights], [1 / 6, 2 / 3, 1 / 6], rtol=1e-15)
    nodes, weights = radau(2)     # Radau IIA, 2 stages
    np.testing.assert_allclose([float(x) for x in nodes], [1 / 3, 1.0], rtol=1e-15)
    np.testing.assert_allclose([float(w) for w in weights], [3 / 4, 1 / 4], rtol=1e-15)
    nodes, weights = radau(3)
    s6 = math.sqrt(6)
    np.testing.assert_allclose([float(x) for x in nodes], [(4 - s6) / 10, (4 + s6) / 10, 1.0],
                               rtol=1e-15)
    np.testing.assert_allclose([float(w) for w in weights], [(16 - s6) / 36, (16 + s6) / 36, 1 / 9],
                               rtol=1e-15)
    assert [float(x) for x in radau(1)[0]] == [1.0]


@pytest.mark.parametrize("rule, n", [(lobatto, 1), (lobatto, 0), (radau, 0)])
def test_too_few_points(rule, n):
    with pytest.raises(ValueError, match="needs at least"):
        rule(n)
