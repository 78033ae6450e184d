"""Gauss-Lobatto and right Gauss-Radau quadrature on [0, 1], computed in high precision.

The nodes are roots of Legendre polynomial combinations, found with mpmath at
``_DPS`` decimal digits, and the weights are integrals of the Lagrange basis,
so every double returned is correctly rounded for q up to well beyond 10.
"""
from functools import cache

import mpmath as mp

_DPS = 60


def _roots(poly_coeffs):
    """Real roots in [-1, 1] of a polynomial given by mpmath coefficients (highest first)."""
    roots = mp.polyroots(poly_coeffs, maxsteps=500, extraprec=4 * _DPS)
    return sorted(mp.re(r) for r in roots)


def _legendre_coeffs(n):
    """Coefficients (highest degree first) of the Legendre polynomial P_n."""
    # Bonnet recursion (k+1) P_{k+1} = (2k+1) x P_k - k P_{k-1}, on coefficient lists (lowest first)
    p_prev, p = [mp.mpf(1)], [mp.mpf(0), mp.mpf(1)]
    if n == 0:
        return p_prev
    for k in range(1, n):
        xp = [mp.mpf(0)] + p
        nxt = [(2 * k + 1) * c for c in xp]
        for i, c in enumerate(p_prev):
            nxt[i] -= k * c
        p_prev, p = p, [c / (k + 1) for c in nxt]
    return list(reversed(p))


def _to_unit_interval(x):
    return [(xi + 1) / 2 for xi in x]


def _weights(nodes):
    """Weights w_m = int_0^1 l_m(s) ds of the Lagrange basis on ``nodes``."""
    n = len(nodes)
    # Solve the moment equations sum_m w_m x_m^j = 1/(j+1), j = 0..n-1, exactly in mpmath.
    V = mp.matrix(n, n)
    rhs = mp.matrix(n, 1)
    for j in range(n):
        for m in range(n):
            V[j, m] = nodes[m] ** j
        rhs[j] = mp.mpf(1) / (j + 1)
    w = mp.lu_solve(V, rhs)
    return [w[m] for m in range(n)]


@cache
def lobatto(n):
    """Gauss-Lobatto rule with ``n >= 2`` points on [0, 1] (exact for degree 2n - 3).

    Nodes are 0, 1 and the roots of P'_{n-1} mapped from [-1, 1].
    Returns (nodes, weights) as tuples of mpmath numbers.
    """
    if n < 2:
        raise ValueError(f"a Lobatto rule needs at least 2 points, got {n}")
    with mp.workdps(_DPS):
        c = _legendre_coeffs(n - 1)
        deg = len(c) - 1
        dc = [c[i] * (deg - i) for i in range(deg)]  # derivative, highest first
        interior = _roots(dc) if len(dc) > 1 else []
        x = [mp.mpf(-1)] + interior + [mp.mpf(1)]
        nodes = _to_unit_interval(x)
        return tuple(nodes), tuple(_weights(nodes))


@cache
def radau(n):
    """Right Gauss-Radau rule with ``n >= 1`` points on [0, 1] (exact for degree 2n - 2).

    The nodes include t = 1 and are the roots of P_n - P_{n-1} mapped from [-1, 1].
    Returns (nodes, weights) as tuples of mpmath numbers.
    """
    if n < 1:
        raise ValueError(f"a Radau rule needs at least 1 point, got {n}")
    with mp.workdps(_DPS):
        pn = _legendre_coeffs(n)
        pm = [mp.mpf(0)] + _legendre_coeffs(n - 1)
        diff = [a - b for a, b in zip(pn, pm)]
        x = _roots(diff) if n > 1 else [mp.mpf(1)]
        x[-1] = mp.mpf(1)  # the root at 1 is exact
        nodes = _to_unit_interval(x)
        return tuple(nodes), tuple(_weights(nodes))
