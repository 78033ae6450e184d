"""Galerkin time-stepping methods cG(q) and dG(q): their nodal weights and bases.

On an element I = (t_{n-1}, t_n] of length k, with tau = (t - t_{n-1}) / k in [0, 1],
the discrete solution U is the polynomial of degree q through its values xi_j at the
method's nodes tau_j. Both methods reduce, after exact quadrature, to the stage form

    xi_s = x0 + k * (b0_s f(x0, t_{n-1}) + sum_m A_sm f(xi_m, t_{n-1} + tau_m k)),

over the stage nodes (the nodes that carry unknowns). The weights come from the
Galerkin equations solved in 60-digit arithmetic (see ``galerkin_weights``).
"""
import re
from dataclasses import dataclass
from functools import cache
from math import factorial

import mpmath as mp
import numpy as np
from numba import njit

from dolfinode.methods.quadrature import _DPS, lobatto, radau

#: The largest degree q: from q = 21 on the step error estimate of u' = -u in double precision
#: is rounding noise (cG(24): 1971 slabs at tolerance 1e-8, cG(20): 23; q >= 30: no progress).
MAX_DEGREE = 20
_METHOD_PATTERN = re.compile(r"^\s*(m?)(cG|dG)\(\s*(\d+)\s*\)\s*$", re.IGNORECASE)
#: scipy's solve_ivp methods and the Galerkin method of the same order and stability
#: (cG(q): nodal order 2q, A-stable; dG(q): order 2q + 1, L-stable, dG(2) is Radau IIA).
_SCIPY_METHODS = {"rk23": "cG(1)", "rk45": "cG(2)", "dop853": "cG(4)", "radau": "dG(2)",
                  "bdf": "dG(1)", "lsoda": "dG(1)"}


@dataclass(frozen=True, eq=False)
class Method:
    """Tables of one Galerkin method (all arrays read-only; float64 but stage_eigenvalues).

    Attributes
    ----------
    family : "cG" or "dG"
    q : polynomial degree of the trial space
    nodes : (q+1,) nodes on [0, 1]; Lobatto for cG (with 0 and 1), right Radau for dG (with 1)
    quadrature_weights : (q+1,) weights of the quadrature rule on the nodes
    stages : indices of the nodes that carry unknowns (1..q for cG, 0..q for dG)
    A : (s, s) weights on the stage values of f
    b0 : (s,) weights on f(x0) (zero for dG)
    end_derivative : (q+1,) l_j'(1), so that k U'(t_n) = sum_j xi_j l_j'(1)
    left_value : (q+1,) l_j(0), so that U(t_{n-1}^+) = sum_j xi_j l_j(0)
    moment_inverse : (s, s) M^{-1}: xi_stages = x0 + k M^{-1} m with the moments
        m_l = int_0^1 f(U(tau), tau) tau^l dtau (l = 0..s-1), for quadrature of one's choice
    stage_transform, stage_transform_inverse : (s, s) real T with A = T B T^{-1}, B block
        diagonal: the real eigenvalues of A (1 x 1 blocks), then each complex pair a +- i b
        as a 2 x 2 block [[a, -b], [b, a]]
    stage_eigenvalues : (r + c,) complex: the r real eigenvalues, then a + i b per pair; the
        simplified Newton matrix I - k A (x) J then splits into I - k lambda J per entry
    order : nodal order of convergence, 2q (cG) or 2q + 1 (dG)
    local_order : order P = q + 1 of the local error estimate k R(t_n) = O(k^P) (both
        families; see :mod:`dolfinode.adaptivity`), which selects the steps
    """

    family: str
    q: int
    nodes: np.ndarray
    quadrature_weights: np.ndarray
    stages: np.ndarray
    A: np.ndarray
    b0: np.ndarray
    end_derivative: np.ndarray
    left_value: np.ndarray
    barycentric_weights: np.ndarray
    moment_inverse: np.ndarray
    stage_transform: np.ndarray
    stage_transform_inverse: np.ndarray
    stage_eigenvalues: np.ndarray

    @property
    def name(self):
        return f"{self.family}({self.q})"

    @property
    def order(self):
        return 2 * self.q if self.family == "cG" else 2 * self.q + 1

    @property
    def local_order(self):
        return self.q + 1

    @property
    def num_stages(self):
        return len(self.stages)

    def basis(self, tau):
        """Lagrange basis l_j(tau) on the nodes, shape (len(tau), q+1), by the barycentric formula."""
        tau = np.atleast_1d(np.asarray(tau, dtype=float))
        diff = tau[:, None] - self.nodes[None, :]
        exact = np.abs(diff) < NODE_HIT
        hit = exact.any(axis=1)
        values = exact.astype(float)
        terms = self.barycentric_weights / diff[~hit]
        values[~hit] = terms / terms.sum(axis=1, keepdims=True)
        return values

    def __repr__(self):
        return f"Method({self.name})"


@njit(cache=True, inline="always")
def real_eigenvalues(eigenvalues):
    """How many of the stage matrix's eigenvalues (``Method.stage_eigenvalues``: the real ones,
    then one per complex pair) are real: the Newton step's real systems."""
    real = 0
    for lam in eigenvalues:
        if lam.imag == 0.0:
            real += 1
    return real


#: |tau - node| below which tau is taken as the node in the barycentric formula: bary_j / d
#: overflowed to inf and the value was inf / inf = NaN (sol(t) at t = 1e-320 after t0 = 0);
#: the interpolant moves by |d| |U'| k there, far below rounding.
NODE_HIT = 1e-250


@njit(cache=True, inline="always")
def element_value(values, e, tau, nodes, bary):
    """The polynomial of element e at tau (in [0, 1], or past it to extrapolate) from its
    nodal values ``values[e, j]`` at ``nodes`` (barycentric Lagrange formula, weights
    ``bary``)."""
    num = 0.0
    den = 0.0
    for j in range(nodes.shape[0]):
        d = tau - nodes[j]
        if abs(d) < NODE_HIT:
            return values[e, j]
        w = bary[j] / d
        num += w * values[e, j]
        den += w
    return num / den


@njit(cache=True, inline="always")
def lagrange_weights(tau, nodes, bary, weights):
    """weights_j = l_j(tau), the Lagrange basis on the nodes at tau (in [0, 1], or past it to
    extrapolate; barycentric formula with weights ``bary``): U(tau) = sum_j weights_j xi_j
    for every component at the cost of one evaluation of the basis."""
    den = 0.0
    for j in range(nodes.shape[0]):
        d = tau - nodes[j]
        if abs(d) < NODE_HIT:  # tau is node j
            for m in range(nodes.shape[0]):
                weights[m] = 0.0
            weights[j] = 1.0
            return
        weights[j] = bary[j] / d
        den += weights[j]
    for j in range(nodes.shape[0]):
        weights[j] /= den


@njit(cache=True, inline="always")
def lagrange_slopes(tau, nodes, slopes):
    """slopes_j = l_j'(tau), the derivative of :func:`lagrange_weights`' basis at tau,

        l_j'(tau) = sum_(m != j) prod_(l != j, m) (tau - tau_l) / (tau_j - tau_l) / (tau_j - tau_m)

    (no division by tau - tau_l: exact at the nodes)."""
    for j in range(nodes.shape[0]):
        slopes[j] = 0.0
        for m in range(nodes.shape[0]):
            if m != j:
                term = 1.0 / (nodes[j] - nodes[m])
                for l in range(nodes.shape[0]):
                    if l != j and l != m:
                        term *= (tau - nodes[l]) / (nodes[j] - nodes[l])
                slopes[j] += term


def monomial_coefficients(nodes):
    """C with c = values @ C: monomial coefficients in tau of the interpolant at the nodes."""
    return np.linalg.inv(np.vander(nodes, increasing=True)).T


def lagrange_matrices(nodes, x):
    """(B, D): B[i, j] = l_j(x_i), D[i, j] = l_j'(x_i) for the Lagrange basis on ``nodes``."""
    C = monomial_coefficients(np.asarray(nodes, dtype=float)).T
    p = np.arange(len(nodes))
    X = np.asarray(x, dtype=float)[:, None]
    B = (X ** p) @ C
    D = (p * X ** np.maximum(p - 1, 0)) @ C
    return B, D


def _lagrange_coefficients(nodes):
    """Monomial coefficients C[j, i] of the Lagrange basis l_j(tau) = sum_i C[j, i] tau^i."""
    n = len(nodes)
    V = mp.matrix(n, n)
    for m in range(n):
        for i in range(n):
            V[m, i] = nodes[m] ** i
    Vinv = mp.inverse(V)  # l_j has coefficients = column j of V^{-1}
    return [[Vinv[i, j] for i in range(n)] for j in range(n)]


def galerkin_weights(family, q):
    """Stage weights (A, b0), end derivative and left values of cG(q) or dG(q), in mpmath.

    cG(q): find U of degree q with U(0) = x0 such that for all v of degree q - 1,
        int_0^1 U' v = k int_0^1 f(U) v      (Lobatto quadrature, q + 1 points).
    dG(q): find U of degree q such that for all v of degree q,
        (U(0^+) - x0) v(0) + int_0^1 U' v = k int_0^1 f(U) v   (Radau quadrature).
    With monomial test functions v_i = tau^i this is M xi = c x0 + k B f, and since
    constants are reproduced exactly, xi = x0 + k M^{-1} B f.
    """
    with mp.workdps(_DPS):
        nodes, weights = lobatto(q + 1) if family == "cG" else radau(q + 1)
        n = q + 1
        C = _lagrange_coefficients(nodes)
        stages = list(range(1, n)) if family == "cG" else list(range(n))
        ntest = len(stages)
        M = mp.matrix(ntest, ntest)
        B = mp.matrix(ntest, n)
        for i in range(ntest):
            for col, j in enumerate(stages):
                # int_0^1 l_j'(tau) tau^i dtau = sum_p C[j][p] p / (p + i)
                integral = mp.fsum(C[j][p] * p / (p + i) for p in range(1, n))
                jump = C[j][0] if (family == "dG" and i == 0) else 0  # l_j(0) v_i(0), v_i(0)=delta_i0
                M[i, col] = integral + jump
            for m in range(n):
                B[i, m] = weights[m] * nodes[m] ** i
        Minv = mp.inverse(M)
        W = Minv * B
        end_derivative = [mp.fsum(C[j][p] * p for p in range(1, n)) for j in range(n)]
        left_value = [C[j][0] for j in range(n)]
        bary = [1 / mp.fprod(nodes[j] - nodes[m] for m in range(n) if m != j) for j in range(n)]
        return nodes, weights, stages, W, end_derivative, left_value, bary, Minv


def stage_eigenstructure(A):
    """Real block diagonalization A = T B T^{-1} of a stage matrix (see :class:`Method`).

    Returns (T, T^{-1}, eigenvalues). The Galerkin stage matrices have distinct eigenvalues
    (cond(T) grows about 4x per degree: 218 for cG(5), 2e6 for cG(12)); T is only used in
    the simplified Newton matrix, so its rounding changes the contraction, not the solution.
    """
    lam, V = np.linalg.eig(A)
    real = [j for j in range(len(lam)) if lam[j].imag == 0.0]
    pairs = [j for j in range(len(lam)) if lam[j].imag > 0.0]
    columns = [V[:, j].real for j in real]
    for j in pairs:
        columns += [V[:, j].real, V[:, j].imag]
    T = np.column_stack(columns)
    T_inverse = np.linalg.inv(T)
    B = T_inverse @ A @ T
    r = len(real)
    eigenvalues = np.array([B[j, j] for j in range(r)]
                           + [complex(B[c, c], B[c + 1, c]) for c in range(r, len(lam), 2)],
                           dtype=complex)
    return T, T_inverse, eigenvalues


def pade(m, n):
    """(numerator, denominator): the coefficients, lowest degree first, of the (m, n) Pade
    approximant of exp(z), P(z) = sum_j a_j z^j / sum_j b_j z^j with

        a_j = (m + n - j)! m! / ((m + n)! j! (m - j)!),
        b_j = (-1)^j (m + n - j)! n! / ((m + n)! j! (n - j)!)."""
    num = [factorial(m + n - j) * factorial(m) / (factorial(m + n) * factorial(j)
                                                    * factorial(m - j)) for j in range(m + 1)]
    den = [(-1) ** j * factorial(m + n - j) * factorial(n)
           / (factorial(m + n) * factorial(j) * factorial(n - j)) for j in range(n + 1)]
    return np.array(num), np.array(den)


def stability_function(method):
    """(numerator, denominator) of ``method``'s stability function R(z), U_n = R(k lambda)
    U_{n-1} on u' = lambda u: the (q, q) Pade approximant of exp(z) for cG(q) (A-stable,
    |R(+-inf)| = 1), the (q, q + 1) one for dG(q) (L-stable, R(+-inf) = 0)."""
    return pade(method.q, method.q + (method.family == "dG"))


def _frozen(values):
    array = np.array([float(v) for v in values], dtype=float)
    array.setflags(write=False)
    return array


def make_method(family, q):
    """The cG(q) (1 <= q <= MAX_DEGREE) or dG(q) (0 <= q <= MAX_DEGREE) method, built once
    and cached."""
    if family not in ("cG", "dG"):
        raise ValueError(f"unknown method family {family!r}: use 'cG' or 'dG'")
    qmin = 1 if family == "cG" else 0
    if isinstance(q, bool) or not isinstance(q, (int, np.integer)) or q < qmin:
        raise ValueError(f"{family}(q) needs an integer q >= {qmin}, got {q!r}")
    if q > MAX_DEGREE:
        raise ValueError(f"{family}(q) needs q <= {MAX_DEGREE}, got {q}: for higher degrees "
                         "the step error estimate is below double-precision rounding; use "
                         f"q <= {MAX_DEGREE} (smaller steps give the same accuracy)")
    return _make_method(family, int(q))


@cache
def _make_method(family, q):
    nodes, weights, stages, W, dend, left, bary, Minv = galerkin_weights(family, q)
    s = len(stages)
    Wf = np.array([[float(W[i, m]) for m in range(q + 1)] for i in range(s)])
    if family == "cG":
        A, b0 = Wf[:, 1:], Wf[:, 0]
    else:
        A, b0 = Wf, np.zeros(s)
    moment_inverse = np.array([[float(Minv[i, j]) for j in range(s)] for i in range(s)])
    T, T_inverse, eigenvalues = stage_eigenstructure(A)
    for array in (A, b0, moment_inverse, T, T_inverse, eigenvalues):
        array.setflags(write=False)
    stage_idx = np.array(stages, dtype=np.int64)
    stage_idx.setflags(write=False)
    return Method(family, q, _frozen(nodes), _frozen(weights), stage_idx, A, b0,
                  _frozen(dend), _frozen(left), _frozen(bary), moment_inverse, T, T_inverse,
                  eigenvalues)


def parse_method(name):
    """Split a method name such as "cG(2)", "dG(0)", "mcG(1)" into (multi_adaptive, Method)."""
    if not isinstance(name, str):
        raise TypeError(f"method must be a string such as 'cG(1)' or 'mdG(0)', got {name!r}")
    return _parse_method(name)


@cache
def _parse_method(name):
    match = _METHOD_PATTERN.match(name)
    if not match:
        similar = _SCIPY_METHODS.get(name.strip().lower())
        hint = (f" ({name!r} is scipy's; a Galerkin method of similar order and stability is "
                f"{similar!r})" if similar else "")
        raise ValueError(f"unknown method {name!r}{hint}: use 'cG(q)' (q >= 1), 'dG(q)' "
                         "(q >= 0), 'mcG(q)', 'mdG(q)' for individual time steps per component, "
                         "or 'auto' (mono or multi-adaptive, chosen by pilot solves)")
    multi, family, q = match.groups()
    family = "cG" if family.lower() == "cg" else "dG"
    return bool(multi), make_method(family, int(q))
