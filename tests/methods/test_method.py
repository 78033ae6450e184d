"""Tables of the Galerkin methods cG(q) and dG(q): closed forms, order conditions, the basis."""
import math

import numpy as np
import pytest

import dolfinode as dn
from dolfinode.methods import make_method
from dolfinode.methods.quadrature import lobatto, radau

Q_MAX = 10
METHODS = [("cG", q) for q in range(1, Q_MAX + 1)] + [("dG", q) for q in range(Q_MAX + 1)]
IDS = [f"{family}({q})" for family, q in METHODS]


@pytest.fixture(params=METHODS, ids=IDS)
def method(request):
    return make_method(*request.param)


def stage_nodes(m):
    return m.nodes[m.stages]


# --- closed forms -----------------------------------------------------------------------------


def test_cg1_is_the_trapezoidal_rule():
    m = make_method("cG", 1)
    np.testing.assert_array_equal(m.nodes, [0.0, 1.0])
    np.testing.assert_array_equal(m.stages, [1])
    np.testing.assert_allclose(m.A, [[0.5]], rtol=1e-15)
    np.testing.assert_allclose(m.b0, [0.5], rtol=1e-15)


def test_cg2_is_lobatto_iiia():
    m = make_method("cG", 2)
    np.testing.assert_allclose(m.nodes, [0.0, 0.5, 1.0], rtol=1e-15)
    np.testing.assert_array_equal(m.stages, [1, 2])
    # Lobatto IIIA, 3 stages: first column is b0, the rest is A (the first stage is x0)
    np.testing.assert_allclose(m.b0, [5 / 24, 1 / 6], rtol=1e-15)
    np.testing.assert_allclose(m.A, [[1 / 3, -1 / 24], [2 / 3, 1 / 6]], rtol=1e-15)


def test_dg0_is_backward_euler():
    m = make_method("dG", 0)
    np.testing.assert_array_equal(m.nodes, [1.0])
    np.testing.assert_array_equal(m.stages, [0])
    np.testing.assert_allclose(m.A, [[1.0]], rtol=1e-15)
    np.testing.assert_array_equal(m.b0, [0.0])


def test_dg1_is_radau_iia():
    m = make_method("dG", 1)
    np.testing.assert_allclose(m.nodes, [1 / 3, 1.0], rtol=1e-15)
    np.testing.assert_allclose(m.A, [[5 / 12, -1 / 12], [3 / 4, 1 / 4]], rtol=1e-15)
    np.testing.assert_array_equal(m.b0, [0.0, 0.0])


def test_dg2_is_radau_iia():
    m = make_method("dG", 2)
    s6 = math.sqrt(6)
    np.testing.assert_allclose(m.nodes, [(4 - s6) / 10, (4 + s6) / 10, 1.0], rtol=1e-15)
    radau_iia = [
        [(88 - 7 * s6) / 360, (296 - 169 * s6) / 1800, (-2 + 3 * s6) / 225],
        [(296 + 169 * s6) / 1800, (88 + 7 * s6) / 360, (-2 - 3 * s6) / 225],
        [(16 - s6) / 36, (16 + s6) / 36, 1 / 9],
    ]
    np.testing.assert_allclose(m.A, radau_iia, rtol=1e-14)
    np.testing.assert_array_equal(m.b0, [0.0, 0.0, 0.0])


# --- structure and order conditions, for every q <= 10 ----------------------------------------


def test_nodes_stages_and_orders(method):
    q = method.q
    rule = lobatto(q + 1) if method.family == "cG" else radau(q + 1)
    np.testing.assert_array_equal(method.nodes, [float(x) for x in rule[0]])
    np.testing.assert_array_equal(method.quadrature_weights, [float(w) for w in rule[1]])
    if method.family == "cG":
        np.testing.assert_array_equal(method.stages, np.arange(1, q + 1))
        assert (method.order, method.local_order, method.num_stages) == (2 * q, q + 1, q)
        assert np.all(method.b0 != 0)
    else:
        np.testing.assert_array_equal(method.stages, np.arange(0, q + 1))
        assert (method.order, method.local_order, method.num_stages) == (2 * q + 1, q + 1, q + 1)
        np.testing.assert_array_equal(method.b0, 0.0)
    s = method.num_stages
    assert method.A.shape == (s, s) and method.b0.shape == (s,)
    assert method.name == f"{method.family}({q})" and repr(method) == f"Method({method.name})"


def test_row_sums_are_the_stage_nodes(method):
    """Consistency: u' = 1 is integrated exactly, xi_s = x0 + k tau_s."""
    np.testing.assert_allclose(method.A.sum(axis=1) + method.b0, stage_nodes(method),
                               rtol=0, atol=1e-14)


def test_last_stage_weights_are_the_quadrature_weights(method):
    """The last stage is the end point t_n: its weights are the quadrature rule's."""
    weights = method.A[-1]
    if method.family == "cG":
        weights = np.concatenate([[method.b0[-1]], weights])
    np.testing.assert_allclose(weights, method.quadrature_weights, rtol=1e-13, atol=1e-15)


def test_stage_equations_integrate_polynomials_exactly(method):
    """sum_m A_sm tau_m^d + b0_s 0^d = tau_s^(d+1) / (d+1) for d <= q: the stage values are exact
    for u' = t^d. Both cG(q) (equivalent to Lobatto IIIA) and dG(q) (Radau IIA) reach d = q,
    one more than the d <= q - 1 that cG(q)'s test space alone guarantees; d = q + 1 fails."""
    tau = stage_nodes(method)
    q = method.q

    def defect(d):
        return np.abs(method.A @ tau**d + method.b0 * 0.0**d - tau ** (d + 1) / (d + 1)).max()

    for d in range(q + 1):
        assert defect(d) < 1e-14, d
    assert defect(q + 1) > 1e-9


def end_value(m, z):
    """U(t_n) for u' = z u, u(0) = 1, k = 1: the stability function R(z) of the method."""
    xi = np.linalg.solve(np.eye(m.num_stages) - z * m.A, 1 + z * m.b0)
    return xi[-1]


def pade(mu, nu, z):
    """The (mu, nu) Pade approximant of e^z (numerator degree mu, denominator degree nu)."""
    f = math.factorial
    num = sum(f(mu + nu - j) * f(mu) / (f(mu + nu) * f(j) * f(mu - j)) * z**j
              for j in range(mu + 1))
    den = sum(f(mu + nu - j) * f(nu) / (f(mu + nu) * f(j) * f(nu - j)) * (-z) ** j
              for j in range(nu + 1))
    return num / den


@pytest.mark.parametrize("z", [-20.0, -3.0, -0.5, 0.25, 1.5])
def test_stability_function_is_the_pade_approximant(method, z):
    """cG(q) has the diagonal (q, q) Pade approximant of e^z as its stability function
    (as Lobatto IIIA), dG(q) the subdiagonal (q, q + 1) one (as Radau IIA)."""
    q = method.q
    expected = pade(q, q, z) if method.family == "cG" else pade(q, q + 1, z)
    assert end_value(method, z) == pytest.approx(expected, rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("family, q", [("cG", 1), ("cG", 2), ("cG", 3), ("dG", 0), ("dG", 1),
                                       ("dG", 2)])
def test_nodal_order_on_the_test_equation(family, q):
    """R(z) = e^z + O(z^(order+1)): halving z divides the error by about 2^(order + 1)."""
    m = make_method(family, q)
    errors = [abs(end_value(m, z) - math.exp(z)) for z in (-0.2, -0.1)]
    assert abs(math.log2(errors[0] / errors[1]) - (m.order + 1)) < 0.3


def test_stiff_limit_of_the_test_equation(method):
    """cG(q) is the diagonal Pade approximant: R(-inf) = (-1)^q (A-stable, not L-stable);
    dG(q) is subdiagonal: R(-inf) = 0 (L-stable)."""
    expected = (-1) ** method.q if method.family == "cG" else 0.0
    assert end_value(method, -1e7) == pytest.approx(expected, abs=1e-4)


# --- the Lagrange basis -------------------------------------------------------------------------


def test_basis_is_the_identity_at_the_nodes(method):
    np.testing.assert_array_equal(method.basis(method.nodes), np.eye(method.q + 1))


def test_basis_is_a_partition_of_unity(method):
    tau = np.random.default_rng(1).uniform(0, 1, 200)
    values = method.basis(tau)
    assert values.shape == (200, method.q + 1)
    np.testing.assert_allclose(values.sum(axis=1), 1.0, rtol=0, atol=1e-13)


def test_basis_reproduces_polynomials_of_degree_q(method):
    tau = np.concatenate([np.random.default_rng(2).uniform(0, 1, 100), [0.0, 1.0]])
    values = method.basis(tau)
    for d in range(method.q + 1):
        np.testing.assert_allclose(values @ method.nodes**d, tau**d, rtol=0, atol=1e-12)
    # for degree q + 1 the interpolation error is the node polynomial prod_j (tau - tau_j)
    node_polynomial = np.prod(tau[:, None] - method.nodes[None, :], axis=1)
    np.testing.assert_allclose(tau ** (method.q + 1) - values @ method.nodes ** (method.q + 1),
                               node_polynomial, rtol=0, atol=1e-12)
    assert np.abs(node_polynomial).max() > 1e-8


def test_lagrange_weights_are_the_basis(method):
    """The compiled basis used for sampling and extrapolation: l_j(tau) at the nodes, inside
    the element and past its end."""
    from dolfinode.methods.method import lagrange_weights

    weights = np.empty(method.q + 1)
    for tau in [*method.nodes, 0.3, 0.77, 1.4, 2.0]:
        lagrange_weights(tau, method.nodes, method.barycentric_weights, weights)
        np.testing.assert_allclose(weights, method.basis(tau)[0], rtol=1e-12, atol=1e-12)


def test_basis_accepts_a_scalar(method):
    assert method.basis(0.5).shape == (1, method.q + 1)
    np.testing.assert_allclose(method.basis(0.5)[0], method.basis(np.array([0.5, 0.7]))[0])


def test_end_derivative_is_the_derivative_of_the_basis_at_one(method):
    # exact identity on polynomials: sum_j l_j'(1) p(tau_j) = p'(1) for deg p <= q
    for d in range(method.q + 1):
        assert method.end_derivative @ method.nodes**d == pytest.approx(
            float(d), abs=1e-11 * max(1.0, np.abs(method.end_derivative).max()))
    # and a fourth-order central finite difference of the basis itself at tau = 1
    h = 1e-3
    values = method.basis(np.array([1 - 2 * h, 1 - h, 1 + h, 1 + 2 * h]))
    fd = (values[0] - 8 * values[1] + 8 * values[2] - values[3]) / (12 * h)
    scale = np.abs(method.end_derivative).max() + 1
    np.testing.assert_allclose(method.end_derivative, fd, rtol=0, atol=1e-5 * scale)


def test_left_value_is_the_basis_at_zero(method):
    np.testing.assert_allclose(method.left_value, method.basis(0.0)[0], rtol=0, atol=1e-13)
    if method.family == "cG":  # 0 is a node: U(t_{n-1}^+) = xi_0 = x0 (continuity)
        np.testing.assert_array_equal(method.left_value, np.eye(method.q + 1)[0])
    for d in range(method.q + 1):
        assert method.left_value @ method.nodes**d == pytest.approx(float(d == 0), abs=1e-11)


def test_stage_eigenstructure_block_diagonalizes_a(method):
    """A = T B T^{-1}, B block diagonal: the real eigenvalues, then [[a, -b], [b, a]] per
    complex pair a + i b; together they are A's eigenvalues (up to conjugation)."""
    A, T, T_inverse = method.A, method.stage_transform, method.stage_transform_inverse
    eigenvalues = method.stage_eigenvalues
    S = A.shape[0]
    np.testing.assert_allclose(T @ T_inverse, np.eye(S), atol=1e-9)
    real = eigenvalues[eigenvalues.imag == 0].real
    pairs = eigenvalues[eigenvalues.imag != 0]
    assert len(real) + 2 * len(pairs) == S
    B = np.zeros((S, S))
    B[range(len(real)), range(len(real))] = real
    for c, mu in enumerate(pairs):
        j = len(real) + 2 * c
        B[j:j + 2, j:j + 2] = [[mu.real, -mu.imag], [mu.imag, mu.real]]
    np.testing.assert_allclose(T @ B @ T_inverse, A, atol=1e-12 * np.linalg.cond(T))
    expected = np.sort_complex(np.linalg.eigvals(A))
    found = np.sort_complex(np.concatenate([real, pairs, pairs.conj()]))
    np.testing.assert_allclose(found, expected, atol=1e-12)
    assert np.all(found.real > 0)  # I - k lambda J is regular for J with eigenvalues in Re <= 0


# --- construction ---------------------------------------------------------------------------------


def test_make_method_is_cached_and_tables_are_read_only():
    a = make_method("cG", 3)
    assert make_method("cG", 3) is a
    assert make_method("dG", 3) is not a
    for array in (a.nodes, a.quadrature_weights, a.stages, a.A, a.b0, a.end_derivative,
                  a.left_value, a.barycentric_weights, a.stage_transform,
                  a.stage_transform_inverse, a.stage_eigenvalues):
        assert not array.flags.writeable
    with pytest.raises(ValueError):
        a.A[0, 0] = 1.0


def test_parse_method_returns_the_cached_method():
    multi_adaptive, m = dn.parse_method("mcG(2)")
    assert multi_adaptive is True
    assert m is make_method("cG", 2)
    multi_adaptive, m = dn.parse_method("dG(1)")
    assert multi_adaptive is False
    assert m is make_method("dG", 1)
