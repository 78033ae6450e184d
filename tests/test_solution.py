"""Solution: exact piecewise-polynomial evaluation, shapes and samples."""
import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode.bench import problems
from dolfinode.compile import lower
from dolfinode.solution import _evaluate_shared


@pytest.mark.parametrize("method", ["cG(3)", "dG(3)", "dG(0)", "cG(1)"])
def test_evaluates_exact_polynomials(method):
    # u' = polynomial of degree q-1 (cG) / q (dG) in t: the Galerkin solution is exact
    q = dn.parse_method(method)[1].q
    u = sp.Symbol("u")
    degree = q - 1 if method.startswith("cG") else q
    ode = dn.ODE({u: dn.t**degree}, u0=[0.0], T=2.0)
    sol = dn.solve(ode, method=method, fixed_time_step=True, initial_time_step=0.5)
    times = np.linspace(0, 2, 37)
    if method.startswith("dG"):
        # dG(q) is exact at the nodes; between them it is the degree-q interpolant there
        times = np.concatenate([sol.t_start + sol.k * tau for tau in sol.method.nodes])
    assert np.allclose(sol(times)[0], times ** (degree + 1) / (degree + 1), atol=1e-13)


def test_shapes_follow_scipy_convention():
    u, v = sp.symbols("u v")
    sol = dn.solve(dn.ODE({u: v, v: -u}, u0=[0, 1], T=1.0), number_of_samples=11)
    assert sol(0.5).shape == (2,)
    assert sol([0.1, 0.2, 0.3]).shape == (2, 3)
    grid = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]])  # any shape: (N, *shape)
    np.testing.assert_array_equal(sol(grid), sol(grid.ravel()).reshape(2, 2, 3))
    assert sol(np.float32(0.5)).shape == (2,) and sol([]).shape == (2, 0)
    assert sol.t.shape == (11,) and sol.y.shape == (2, 11)
    assert sol.t[0] == 0.0 and sol.t[-1] == 1.0
    np.testing.assert_allclose(sol.y[:, 0], [0, 1])


@pytest.mark.parametrize("method", ["cG(2)", "mcG(2)"])
def test_samples_are_made_when_first_read(method):
    """sol.t and sol.y are made on first access (not by solve), once, and are the solution at
    the equispaced sample times."""
    u, v = sp.symbols("u v")
    sol = dn.solve(dn.ODE({u: v, v: -u}, u0=[0, 1], T=2.0), method, number_of_samples=7)
    assert "t" not in vars(sol) and "y" not in vars(sol)
    y = sol.y
    assert sol.y is y and "t" in vars(sol)
    np.testing.assert_array_equal(sol.t, np.linspace(0.0, 2.0, 7))
    np.testing.assert_allclose(y, sol(sol.t), rtol=0, atol=0)


@pytest.mark.parametrize("method, steps, order", [
    ("mcG(2)", (0.2, 0.1, 0.05), 4), ("mcG(3)", (0.4, 0.2, 0.1), 6),
    ("mdG(1)", (0.1, 0.05, 0.025), 3), ("mdG(2)", (0.2, 0.1, 0.05), 5)])
def test_multi_values_inside_elements_converge_with_the_defect_correction(method, steps, order):
    """mcG(q), mdG(q) are evaluated inside their elements by the defect-corrected collocation
    polynomial V = P - g S, as mono cG(q), dG(q): on the harmonic oscillator with fixed steps
    k for u and k / 2 for v (each reading the other inside its elements), the largest error
    at tau = 0.3, 0.5, 0.7 of every element converges with order min(q + 3, the nodes')
    (measured 4.0, 6.0, 3.0, 5.0; the collocation polynomial alone, as before: 4, 5, 2, 4),
    the polynomial U's with q + 1, and the values at the element ends are U's nodal values."""
    u, v = sp.symbols("u v")
    ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=2.0)
    q = dn.parse_method(method)[1].q
    dense, galerkin = [], []
    for k in steps:
        sol = dn.solve(ode, method, fixed_time_step=True, initial_time_step={u: k, v: k / 2})
        worst = np.zeros(2)
        for i, exact in enumerate((np.cos, lambda t: -np.sin(t))):
            a, h = sol.time_steps(i)
            t = (a[:, None] + h[:, None] * np.array([0.3, 0.5, 0.7])).ravel()
            worst = np.maximum(worst, [np.max(np.abs(sol(t)[i] - exact(t))),
                                       np.max(np.abs(sol._galerkin(t)[i] - exact(t)))])
            np.testing.assert_array_equal(sol(a + h)[i], sol._galerkin(a + h)[i])
        dense.append(worst[0])
        galerkin.append(worst[1])
    assert np.all(np.log2(np.divide(dense[:-1], dense[1:])) > order - 0.3), dense
    if method.startswith("mcG"):  # (mdG(q)'s _galerkin is its collocation polynomial)
        assert np.all(np.abs(np.log2(np.divide(galerkin[:-1], galerkin[1:])) - (q + 1)) < 0.2)


def _lotka_volterra():
    x, y = sp.symbols("x y")
    return (dn.ODE({x: 1.5 * x - x * y, y: -3 * y + x * y}, u0=[1.0, 1.0], T=10.0),
            lambda t, z: [1.5 * z[0] - z[0] * z[1], -3 * z[1] + z[0] * z[1]])


def _forced_decay_pair():
    x, y = sp.symbols("x y")  # x' = -x + sin 10 t driving y' = -y / 2 + x
    return (dn.ODE({x: -x + sp.sin(10 * dn.t), y: -0.5 * y + x}, u0=[1.0, 0.0], T=3.0),
            lambda t, z: [-z[0] + np.sin(10 * t), -0.5 * z[1] + z[0]])


@pytest.mark.parametrize("problem", [_lotka_volterra, _forced_decay_pair])
@pytest.mark.parametrize("method", ["mcG(2)", "mcG(3)", "mdG(1)", "mdG(2)", "mdG(3)"])
def test_multi_interior_error_within_the_tolerance(problem, method):
    # adaptive steps, tolerance 1e-7: inside every component's elements (tau = 0.1..0.9)
    # mcG(q), mdG(q) are within a few times the tolerance, as at the ends (measured 0.09-2.2
    # x; the collocation polynomial per component before: mcG(3) 2.1 / 32, mdG(1) 44 / 63,
    # mdG(2) 10 / 18, mdG(3) 10 / 9.3 x on the two problems)
    ode, f = problem()
    reference = solve_ivp(f, (ode.t0, ode.T), ode.u0, method="DOP853", rtol=1e-13,
                          atol=1e-15, dense_output=True).sol
    sol = dn.solve(ode, method, tolerance=1e-7)
    for i in range(ode.N):
        a, h = sol.time_steps(i)
        t = (a[:, None] + h[:, None] * np.arange(1, 10) / 10).ravel()
        exact = reference(t)
        error = np.abs(sol(t)[i] - exact[i]).max() / (1e-7 * (1 + np.abs(exact[i]).max()))
        assert error < 3.0, f"{ode.states[i]}: inside {error:.3g} x"


def _switched_follower():
    # u' = -500 (u - H(v - 1/2) v) follows v = sin t while v > 1/2, else decays to 1e-40
    u, v = sp.symbols("u v")
    f = {u: -500 * (u - sp.Heaviside(v - sp.Rational(1, 2)) * v), v: sp.cos(dn.t)}
    return dn.ODE(f, u0=[0.0, 0.0], T=6.0), "mdG(2)", lambda t: np.sin(t)


def _stiff_follower():
    # u' = -800 (u - sin(v)^3), stiff, stepped over, read by v' = 1 - v / 5 + u / 10
    u, v = sp.symbols("u v")
    ode = dn.ODE({u: -800 * (u - sp.sin(v) ** 3), v: 1 - v / 5 + u / 10}, u0=[0.0, 0.0],
                 T=6.0)
    reference = solve_ivp(lambda t, z: [-800 * (z[0] - np.sin(z[1]) ** 3),
                                        1 - z[1] / 5 + z[0] / 10], (0.0, 6.0), [0.0, 0.0],
                          method="Radau", rtol=1e-12, atol=1e-13, dense_output=True).sol
    return ode, "mdG(1)", lambda t: reference(t)[1]


@pytest.mark.parametrize("problem", [_switched_follower, _stiff_follower])
def test_mdg_dense_value_of_a_slow_component_beside_a_stiff_one(problem):
    # v shares its elements with u, whose tests fail (u at 1e-40, or k |J_uu| = 54): the
    # shared kind is U, and U (each element's polynomial after its jump) was 64 x and 17 x
    # the tolerance off just after an element's start, where the element polynomial read
    # without f (dG's jump rule) is 0.03 x and 0.012 x; now 0.25 x and 0.24 x
    ode, method, exact = problem()
    sol = dn.solve(ode, method, tolerance=1e-6)
    t = np.linspace(0.0, 6.0, 6001)
    scale = 1e-6 * np.maximum(np.abs(exact(t)), 1.0)
    error = (np.abs(sol(t)[1] - exact(t)) / scale).max()
    galerkin = (np.abs(sol._galerkin(t)[1] - exact(t)) / scale).max()
    assert error <= 3.0 * max(galerkin, 1.0), f"inside {error:.3g} x, the polynomial's {galerkin:.3g} x"


@pytest.mark.parametrize("method", ["mcG(2)", "mcG(3)", "mdG(1)", "mdG(2)"])
def test_multi_dense_values_keep_linear_invariants_on_shared_intervals(method):
    # x + y + z = 1 (w^T f = 0): the components coupled over elements of one interval take
    # one kind of value there (V, P or U: corrections linear in f), so the sum holds inside
    # as at the nodes (a kind per component: mcG(2) 9.4e-9; U: mdG(1) 2e-5, its components
    # on one partition, each element's U starting after its jump)
    x, y, z = sp.symbols("x y z")
    ode = dn.ODE({x: -x + 0.5 * y, y: x - 20.5 * y + 5 * z, z: 20 * y - 5 * z},
                 u0=[1.0, 0.0, 0.0], T=5.0)
    sol = dn.solve(ode, method, tolerance=1e-6)
    a, h = sol.time_steps(0)
    inside = (a[:, None] + h[:, None] * np.arange(1, 10) / 10).ravel()
    dense = sol(inside)
    assert np.mean(np.any(dense != sol._galerkin(inside), axis=0)) > 0.5  # (corrected)
    assert np.abs(dense.sum(axis=0) - 1.0).max() <= 1e-14


def test_values_at_element_ends_are_nodal_values():
    u = sp.Symbol("u")
    sol = dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0), method="dG(2)", tolerance=1e-6)
    ends = sol.t_start + sol.k
    np.testing.assert_allclose(sol(ends)[0], sol.values[:, -1, 0], rtol=1e-14)


def test_outside_interval_raises():
    u = sp.Symbol("u")
    sol = dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0))
    with pytest.raises(ValueError, match="defined on"):
        sol(1.5)
    with pytest.raises(ValueError, match=r"defined on \[0.0, 1.0\], got t = nan \(not a number\)"):
        sol(np.nan)
    with pytest.raises(ValueError, match=r"got t = 1.5$"):
        sol([0.5, 1.5, 0.2])


@pytest.mark.parametrize("t", ["a", 1j, [0.5, "b"], None])
def test_time_that_is_not_a_real_number_raises_type_error(t):
    # sol("a") raised numpy's "could not convert string to float", sol(1j) float()'s message
    u = sp.Symbol("u")
    sol = dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0))
    with pytest.raises(TypeError, match="the solution is evaluated at real times t"):
        sol(t)


def test_time_steps_of_a_component_index_out_of_range():
    # a multi-adaptive solution's time_steps(99) raised a bare IndexError and time_steps(-1)
    # returned empty arrays
    u, v = sp.symbols("u v")
    sol = dn.solve(dn.ODE({u: -u, v: -10 * v}, u0=[1.0, 1.0], T=1.0), "mcG(1)")
    for bad in (2, 99, -3):
        with pytest.raises(ValueError, match="component index .* out of range: 2 components"):
            sol.time_steps(bad)
    start, k = sol.time_steps(-1)
    assert np.array_equal(start, sol.time_steps(v)[0]) and len(k) > 0


@pytest.mark.parametrize("method", ["dG(0)", "dG(2)", "cG(2)"])
def test_initial_time_gives_initial_value(method):
    u = sp.Symbol("u")
    sol = dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0), method=method, tolerance=1e-3)
    assert sol(0.0)[0] == 1.0 and sol.y[0, 0] == 1.0


@pytest.mark.parametrize("method", ["cG(1)", "cG(2)", "dG(2)", "mcG(2)"])
def test_times_a_subnormal_distance_after_t0(method):
    """sol(t) for t = 5e-324 .. 1e-310 after t0 = 0: tau is that close to a node, where the
    barycentric weight bary_j / (tau - node) overflowed and the value was inf / inf = NaN
    (every method but dG(0) and mdG(2)). It is the initial value to rounding."""
    u, v = sp.symbols("u v")
    sol = dn.solve(dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=6.0), method, tolerance=1e-6)
    times = np.array([5e-324, 1e-320, 1e-310, 1e-300])
    assert np.allclose(sol(times), np.repeat([[1.0], [0.0]], times.size, axis=1),
                       rtol=0.0, atol=1e-15)
    assert np.allclose(sol.method.basis(times), np.repeat(sol.method.basis(0.0), 4, axis=0),
                       rtol=0.0, atol=1e-15)


def test_evaluation_is_the_element_polynomial():
    """U(t) on the shared partition is the Lagrange polynomial of the element containing t
    (the left one at element ends): against the method's basis, at many times (sol(t) is
    cG(q)'s dense value, the same at the element ends)."""
    u, v = sp.symbols("u v")
    sol = dn.solve(dn.ODE({u: v, v: -u}, u0=[0, 1], T=3.0), method="cG(2)", tolerance=1e-8)
    times = np.linspace(0, 3, 1001)[1:]
    t_end = sol.t_start + sol.k
    n = np.searchsorted(t_end, times)
    basis = sol.method.basis((times - sol.t_start[n]) / sol.k[n])
    expected = np.einsum("mj,mjn->nm", basis, sol.values[n])
    np.testing.assert_allclose(sol._galerkin(times), expected, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(sol(t_end[:5]), sol.values[:5, -1].T)


def _searched(sol, times):
    """U at ``times`` located by one search per time (np.searchsorted in the element ends,
    per component for multi-adaptive solutions), the reference of the walk in sol(t)."""
    from dolfinode.methods.method import element_value, lagrange_weights

    nodes, bary = sol.method.nodes, sol.method.barycentric_weights
    weights = np.empty(nodes.size)
    out = np.empty((sol.ode.N, times.size))
    for i in range(sol.ode.N):
        if sol.multi:
            span = slice(sol._component_ptr[i], sol._component_ptr[i + 1])
            t_start, t_end, values = sol.t_start[span], sol._t_end[span], sol.values[span]
        else:
            t_start, t_end, values = sol.t_start, sol.t_start + sol.k, sol.values[:, :, i]
        for m, t in enumerate(times):
            e = min(np.searchsorted(t_end, t), t_end.size - 1)
            tau = min(max((t - t_start[e]) / (t_end[e] - t_start[e]), 0.0), 1.0)
            if sol.multi:
                out[i, m] = element_value(values, e, tau, nodes, bary)
            else:  # the basis once per time for all components, as sol(t)
                lagrange_weights(tau, nodes, bary, weights)
                out[i, m] = sum(weights[j] * values[e, j] for j in range(nodes.size))
    out[:, times == sol.ode.t0] = sol.ode.u0[:, None]
    return out


@pytest.mark.parametrize("method", ["dG(2)", "cG(2)", "mcG(1)"])
def test_evaluation_at_many_times_locates_as_a_search_per_time(method):
    """sol(times) locates the elements by a walk over sorted times (galloping over sparse
    ones, bisecting back for an earlier time): the same values bitwise as a search per time,
    for sorted, shuffled and sparse times, element ends, t0 and T."""
    u, v, w = sp.symbols("u v w")
    ode = dn.ODE({u: v, v: -u, w: -20 * w}, u0=[0, 1, 1], T=3.0)
    sol = dn.solve(ode, method=method, tolerance=1e-5)
    rng = np.random.default_rng(0)
    ends = np.concatenate([sol.t_start, sol.t_start + sol.k])
    many = np.sort(np.concatenate([[0.0, 3.0], ends, rng.uniform(0, 3, 300)]))
    for times in (many, rng.permutation(many), np.array([0.0, 1e-9, 2.9, 3.0]), many[::-1]):
        if sol.method.q > 0 and not sol.multi:  # (the collocation dense output)
            expected = np.column_stack([sol(t) for t in times])
        else:
            expected = _searched(sol, times)
        np.testing.assert_array_equal(sol(times), expected)
    assert sol.k.size > 20


def test_join_elements_concatenates_and_empties_the_chunks():
    from dolfinode.solution import join_elements

    rng = np.random.default_rng(1)
    chunks = [[rng.random(n), rng.random((n, 2, 3))] for n in (4, 1, 7)]
    expected = [np.concatenate(parts) for parts in zip(*chunks)]
    joined = join_elements(chunks)
    assert chunks == []
    for a, b in zip(joined, expected):
        assert np.array_equal(a, b)


def test_a_solve_that_reaches_T_says_so_as_solve_ivp():
    x = sp.Symbol("x")
    sol = dn.solve(dn.ODE({x: -x}, u0=[1.0], T=1.0), "cG(1)", tolerance=1e-4)
    assert (sol.success, sol.status) == (True, 0)
    assert sol.message == "The solver successfully reached the end of the integration interval."
    # set at construction, with nothing attached afterwards
    assert sol.parameters["tolerance"] == 1e-4
    assert sol.model is None and sol.error_estimate is None


def test_a_failed_solve_raises_an_error_with_failure_status():
    x = sp.Symbol("x")
    with pytest.raises(dn.SolverError) as info:
        dn.solve(dn.ODE({x: x**2}, u0=[1.0], T=2.0), "cG(1)", tolerance=1e-4)
    assert (info.value.success, info.value.status) == (False, -1)
    assert info.value.message == str(info.value)


def test_ode_and_stats_given_by_makers_are_made_once_on_first_read():
    """A solve may give makers for sol.ode and sol.stats (the prepared path of dn.Solver):
    each is called once, when first read, or before pickling; the solution is the same.
    (cG(1): its dense value reads no f; cG(q), q >= 2, and dG(q), q >= 1, make the ode to
    lower it when first evaluated.)"""
    u = sp.Symbol("u")
    eager = dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0), method="cG(1)")
    calls = []

    def maker(value):
        return lambda: calls.append(value) or value

    lazy = dn.Solution(None, eager.method, eager.t_start, eager.k, eager.values, None, 11,
                       makers={"ode": maker(eager.ode), "stats": maker(eager.stats)})
    assert calls == [] and lazy.stats is eager.stats and lazy.stats is eager.stats
    np.testing.assert_array_equal(lazy(0.5), eager(0.5))  # (reads ode)
    assert calls == [eager.stats, eager.ode]
    import pickle

    fresh = dn.Solution(None, eager.method, eager.t_start, eager.k, eager.values, None, 11,
                        makers={"ode": maker(eager.ode), "stats": maker(eager.stats)})
    copy = pickle.loads(pickle.dumps(fresh))
    np.testing.assert_array_equal(copy.y, eager(np.linspace(0.0, 1.0, 11)))
    assert copy.stats == eager.stats and "_makers" not in vars(copy)
    # given the declaration the ode maker copies, evaluation reads it and makes no ode
    calls.clear()
    declared = dn.Solution(None, eager.method, eager.t_start, eager.k, eager.values, None, 11,
                           makers={"ode": maker(eager.ode), "stats": maker(eager.stats),
                                   "declared": eager.ode})
    np.testing.assert_array_equal(declared([0.0, 0.5]), eager([0.0, 0.5]))
    np.testing.assert_array_equal(declared.y, eager(np.linspace(0.0, 1.0, 11)))
    assert calls == [] and declared.ode is eager.ode and calls == [eager.ode]
    pickle.loads(pickle.dumps(eager))  # (an eager solution pickles as before)


# --- dense output of mono-adaptive dG(q) and cG(q): collocation polynomials inside ---

def _harmonic(T):
    from dolfinode.bench.problems import linear
    return linear(np.array([[0.0, 1.0], [-1.0, 0.0]]), np.array([1.0, 0.0]), T)[0]


@pytest.mark.parametrize("family", ["dG", "cG"])
@pytest.mark.parametrize("q", [2, 3])
def test_dense_interior_order(family, q):
    # fixed steps k: the interior error of sol(t) falls as k^(q+2) (the Galerkin polynomial's
    # as k^(q+1)); measured slopes on the harmonic oscillator (dG(q): Radau collocation,
    # cG(q): Lobatto IIIA collocation)
    ode = _harmonic(4.0)
    t = np.linspace(0.0, 4.0, 997)[1:]
    exact = np.array([np.cos(t), -np.sin(t)])
    errors = []
    for k in (0.2, 0.1):
        sol = dn.solve(ode, method=f"{family}({q})", initial_time_step=k, fixed_time_step=True)
        errors.append(np.abs(sol(t) - exact).max())
    slope = np.log2(errors[0] / errors[1])
    assert slope > q + 1.6, f"interior slope {slope:.2f}"


@pytest.mark.parametrize("family, q", [("dG", 2), ("dG", 3), ("cG", 3), ("cG", 4)])
def test_dense_interior_order_with_the_defect_correction(family, q):
    # fixed steps k: the defect-corrected interior error falls as k^(q+3) (the collocation
    # polynomials' as k^(q+2), measured 4.0, 5.0 (dG), 5.1, 6.0 (cG) here; the nodes' as
    # k^(2q+1) (dG), k^(2q) (cG))
    ode = _harmonic(4.0)
    t = np.linspace(0.0, 4.0, 997)[1:]
    exact = np.array([np.cos(t), -np.sin(t)])
    errors = [np.abs(dn.solve(ode, method=f"{family}({q})", initial_time_step=k,
                              fixed_time_step=True)(t) - exact).max() for k in (0.4, 0.2)]
    slope = np.log2(errors[0] / errors[1])
    assert slope > q + 2.6, f"interior slope {slope:.2f}"


@pytest.mark.parametrize("q", [2, 3, 4])
def test_dense_cg_interior_error_within_the_tolerance(q):
    # adaptive steps, tolerance 1e-8, u' = cos t + 1.5 cos 3t: inside the elements
    # (tau = 0.05..0.95) cG(q) is within the tolerance, as at their ends (the collocation
    # polynomial alone: 6.5, 15 and 6.8 x, in elements the step control let grow 1.3-1.6 x
    # past their neighbours where the end residual is small)
    u = sp.Symbol("u")
    ode = dn.ODE({u: sp.cos(dn.t) + 1.5 * sp.cos(3 * dn.t)}, u0=[0.0], T=10.0)
    sol = dn.solve(ode, method=f"cG({q})", tolerance=1e-8)
    inside = (sol.t_start[:, None] + sol.k[:, None] * np.arange(1, 20) / 20).ravel()
    error = np.abs(sol(inside)[0] - np.sin(inside) - np.sin(3 * inside) / 2).max()
    assert error < 3e-8 * (1 + 1.5), f"inside {error:.3g}"


@pytest.mark.parametrize("case, method", [("linear", "cG(3)"), ("algebraic", "cG(2)")])
def test_dense_cg_interior_error_of_a_singular_perturbation(case, method):
    # eps = 1e-10, stepped over: the element's value is W = U + c Q - g S, the linearised
    # equation collocated at two points (the stiff component at its quasi-steady state; U
    # alone: 181 x (linear, cG(3)) and 27 x (algebraic, cG(2)); one point, U + c Q: 24.5 x
    # on the linear one, in its non-stiff component)
    eps = 1e-10
    u, v = sp.symbols("u v")
    if case == "linear":  # u' = -u + v, eps v' = sin t - v
        ode = dn.ODE({u: -u + v, v: (sp.sin(dn.t) - v) / eps}, u0=[1.0, 0.0], T=5.0)
        f = lambda t, y: [-y[0] + y[1], (np.sin(t) - y[1]) / eps]
        jac = lambda t, y: [[-1.0, 1.0], [0.0, -1 / eps]]
    else:  # u' = -v, eps v' = u - v - v^3
        ode = dn.ODE({u: -v, v: (u - v - v**3) / eps}, u0=[2.0, 1.0], T=3.0)
        f = lambda t, y: [-y[1], (y[0] - y[1] - y[1] ** 3) / eps]
        jac = lambda t, y: [[0.0, -1.0], [1 / eps, -(1 + 3 * y[1] ** 2) / eps]]
    ref = solve_ivp(f, (0.0, ode.T), ode.u0, method="Radau", rtol=1e-12, atol=1e-14, jac=jac,
                    dense_output=True)
    sol = dn.solve(ode, method=method, tolerance=1e-8)
    inside = (sol.t_start[:, None] + sol.k[:, None] * np.arange(1, 20) / 20).ravel()
    exact = ref.sol(inside)
    error = (np.abs(sol(inside) - exact) / (1e-8 + 1e-8 * np.abs(exact))).max()
    assert error < 3.0, f"inside {error:.3g} x"


@pytest.mark.parametrize("method", ["cG(2)", "cG(3)"])
def test_dense_cg_keeps_linear_invariants_inside_elements(method):
    # ROBER conserves y1 + y2 + y3 = 1 and HIRES y7 + y8; U and every corrected value keep
    # them (corrections linear in f, one kind per element for all components). A kind
    # chosen per component broke them: ROBER 1.6e-6 (cG(2)), 3.1e-8 (cG(3)) at 1e-6
    from dolfinode.bench import problems as P
    for ode, w, value in ((P.rober(T=40.0).ode, [0, 1, 2], 1.0), (P.hires(), [6, 7], 0.0057)):
        sol = dn.solve(ode, method=method, tolerance=1e-6)
        inside = (sol.t_start[:, None] + sol.k[:, None] * np.arange(1, 20) / 20).ravel()
        dense = sol(inside)
        assert np.mean(np.any(dense != sol._galerkin(inside), axis=0)) > 0.5  # (corrected)
        assert np.abs(dense[w].sum(axis=0) - value).max() <= 1e-14 * value


def _forced_decay():
    u = sp.Symbol("u")  # u' = -u + sin 10 t, u(0) = 1
    return (dn.ODE({u: -u + sp.sin(10 * dn.t)}, u0=[1.0], T=3.0),
            lambda t: (111 * np.exp(-t) + np.sin(10 * t) - 10 * np.cos(10 * t)) / 101)


@pytest.mark.parametrize("method, problem", [("dG(1)", "harmonic"), ("dG(1)", "forced"),
                                             ("dG(2)", "forced")])
def test_dense_dg_interior_error_within_the_tolerance(method, problem):
    # adaptive steps, tolerance 1e-6: inside the elements (tau = 0.1..0.9) dG(q) is within
    # a few times the tolerance, as at their ends (the jump test alone gave 20 x, 27 x and
    # 8.5 x: dG(1) at the extrema of a component, dG(2) the collocation polynomial's order)
    ode, exact = ((_harmonic(20.0), lambda t: np.array([np.cos(t), -np.sin(t)]))
                  if problem == "harmonic" else _forced_decay())
    sol = dn.solve(ode, method=method, tolerance=1e-6)
    inside = (sol.t_start[:, None] + sol.k[:, None] * np.arange(1, 10) / 10).ravel()
    error = np.abs(sol(inside) - exact(inside)).max()
    assert error < 3e-6 * (1 + np.abs(exact(inside)).max()), f"inside {error:.3g}"


def test_dense_dg_nodes_bitwise_and_continuous():
    # at the element ends sol(t) is the end node value, bit for bit; the collocation
    # polynomial starts at the previous end value (continuous from the left)
    sol = dn.solve(_harmonic(5.0), method="dG(2)", tolerance=1e-6)
    ends = sol.t_start + sol.k
    assert np.array_equal(sol(ends), sol.values[:, -1, :].T)
    eps = 1e-9 * sol.k[1:]
    right = sol(sol.t_start[1:] + eps)
    assert np.abs(right - sol.values[:-1, -1, :].T).max() < 1e-6


@pytest.mark.parametrize("q", [1, 2, 3])
def test_dense_dg_no_overshoot_on_stepped_over_decay(q):
    # u' = -1e4 u, u(0) = -1, stepped over by steps >> 1e-4: the dense values stay in
    # [-1, 0] up to the Galerkin values' own swing (the
    # collocation polynomial, |[U] R(tau)| ~ 0.4 |[U]| inside, is not used there)
    from dolfinode.bench.problems import linear
    ode = linear(np.array([[-1e4, 0.0], [0.0, -1.0]]), np.array([-1.0, -1.0]), 1.0)[0]
    sol = dn.solve(ode, method=f"dG({q})", initial_time_step=0.05, fixed_time_step=True)
    t = np.linspace(0.0, 1.0, 2001)[1:]
    y = sol(t)[0]
    galerkin = np.empty((t.size, 2)).T
    _evaluate_shared(sol.t_start, sol.t_start + sol.k, sol.values, sol.method.nodes,
                     sol.method.barycentric_weights, t, galerkin)
    # no swing beyond the Galerkin polynomial's (a few 1e-2 here; the collocation
    # polynomial through u(0) = -1 would reach about 0.4)
    assert y.min() >= -1.0 and np.abs(y).max() <= np.abs(galerkin[0]).max() < 0.05


def test_dense_dg_every_evaluation_path_agrees():
    # sol.y (sample_times and equispaced), sol(array), sol(scalar) give the same dense values,
    # u0 at t0 and the last node at T, and differ from the Galerkin polynomial inside
    ode = _harmonic(5.0)
    times = np.concatenate([[0.0], np.sort(np.random.default_rng(3).uniform(0, 5, 50)), [5.0]])
    sol = dn.solve(ode, method="dG(2)", tolerance=1e-6, sample_times=times)
    scalar = np.column_stack([sol(t) for t in times])
    np.testing.assert_array_equal(sol.y, sol(times))
    np.testing.assert_array_equal(sol(times), scalar)
    np.testing.assert_array_equal(sol(0.0), ode.u0)
    np.testing.assert_array_equal(sol(5.0), sol.values[-1, -1])
    equispaced = dn.solve(ode, method="dG(2)", tolerance=1e-6, number_of_samples=40)
    np.testing.assert_array_equal(equispaced.y, sol(equispaced.t))
    galerkin = np.empty((times.size, 2)).T
    _evaluate_shared(sol.t_start, sol.t_start + sol.k, sol.values, sol.method.nodes,
                     sol.method.barycentric_weights, times, galerkin)
    exact = np.array([np.cos(times), -np.sin(times)])
    assert np.abs(sol.y - exact).max() < 0.2 * np.abs(galerkin - exact)[:, 1:-1].max()


def test_dense_cg_nodes_bitwise_and_every_path_agrees():
    # at the element ends sol(t) is the end node value, bit for bit; sol.y, sol(array), sol(scalar) and dense_output=False agree (a stored history:
    # tests/io/test_stored.py)
    ode = _harmonic(5.0)
    times = np.concatenate([[0.0], np.sort(np.random.default_rng(3).uniform(0, 5, 50)), [5.0]])
    sol = dn.solve(ode, method="cG(3)", tolerance=1e-6, sample_times=times)
    np.testing.assert_array_equal(sol(sol.t_start + sol.k), sol.values[:, -1, :].T)
    np.testing.assert_array_equal(sol.y, sol(times))
    np.testing.assert_array_equal(sol(times), np.column_stack([sol(t) for t in times]))
    sampled = dn.solve(ode, method="cG(3)", tolerance=1e-6, sample_times=times,
                       dense_output=False)
    np.testing.assert_array_equal(sampled.y, sol.y)
    assert not np.array_equal(sol(times), sol._galerkin(times))


@pytest.mark.parametrize("method", ["cG(2)", "cG(3)", "mcG(3)"])
@pytest.mark.parametrize("jump", ["step", "decay"])
def test_dense_cg_where_f_jumps_in_t_reads_f_on_the_elements_side(method, jump):
    # each element solves the branch of its piece; f read at an end node on the jump (t = 1)
    # gives the other: the collocation polynomial was 640 x the tolerance there, and the
    # element polynomial used instead 15-27 x inside on the decay at 1e-8
    u, v = sp.symbols("u v")
    t = dn.t
    if jump == "step":
        rhs, tolerance = {u: sp.Piecewise((1, t < 1), (3, True)), v: -v}, 1e-6
        exact = lambda s: np.where(s < 1, s, 1 + 3 * (s - 1))
    else:
        rhs, tolerance = {u: -u + sp.Heaviside(t - 1), v: u - 2 * v}, 1e-8
        exact = lambda s: np.exp(-s) + np.where(s > 1, 1 - np.exp(1 - s), 0.0)
    sol = dn.solve(dn.ODE(rhs, u0=[float(exact(0.0)), 1.0], T=3.0), method=method,
                   tolerance=tolerance)
    times = np.linspace(0.0, 3.0, 3001)
    error = np.abs(sol(times)[0] - exact(times)) / (tolerance * (1 + np.abs(exact(times))))
    assert sol.stats["breakpoints"] == 1
    assert error.max() < 2.0


@pytest.mark.parametrize("method", ["dG(1)", "mdG(1)", "dG(2)"])
@pytest.mark.parametrize("jump", ["step", "kink"])
def test_dense_dg_where_f_jumps_reads_f_inside_the_element(method, jump):
    # dG's dense value reads f only inside an element, which no jump crosses; without f,
    # dG(1) fell back to U near an extremum of u: 15-69 x the tolerance inside elements
    u, v = sp.symbols("u v")
    t = dn.t
    if jump == "step":  # u = sin t + (t - 3.3)_+ / 2, an extremum at pi / 2
        rhs, T = {u: sp.cos(t) + sp.Heaviside(t - 3.3) / 2, v: -v}, 4.0
        exact = lambda s: np.sin(s) + np.maximum(s - 3.3, 0) / 2
    else:  # u' = |t - 0.4| u: u' = 0 at the kink
        rhs, T = {u: sp.Abs(t - 0.4) * u, v: -v}, 1.0
        exact = lambda s: np.exp(np.where(s < 0.4, 0.4 * s - s**2 / 2,
                                          0.08 + (s - 0.4) ** 2 / 2))
    tolerance = 1e-7
    sol = dn.solve(dn.ODE(rhs, u0=[0.0 if jump == "step" else 1.0, 1.0], T=T), method=method,
                   tolerance=tolerance)
    times = np.linspace(0.0, T, 4001)
    error = np.abs(sol(times)[0] - exact(times)) / (tolerance * (1 + np.abs(exact(times))))
    assert sol.stats["breakpoints"] >= 1
    assert error.max() < 3.0


def test_dense_dg_across_a_state_switch_keeps_its_accuracy():
    # f on the wrong side of a switch in u fails the residual test: U, not a wrong P
    u, v = sp.symbols("u v")
    ode = dn.ODE({u: sp.cos(dn.t) + sp.Heaviside(u - sp.Rational(1, 2)) * u, v: -v},
                 u0=[0.0, 1.0], T=2.0)
    reference = solve_ivp(lambda t, y: [np.cos(t) + (y[0] > 0.5) * y[0], -y[1]], (0.0, 2.0),
                          [0.0, 1.0], method="Radau", rtol=1e-12, atol=1e-14,
                          dense_output=True)
    for method in ["dG(1)", "dG(2)", "mdG(1)"]:
        sol = dn.solve(ode, method=method, tolerance=1e-6)
        times = np.linspace(0.0, 2.0, 2001)
        exact = reference.sol(times)[0]
        error = np.abs(sol(times)[0] - exact) / (1e-6 * (1 + np.abs(exact)))
        assert error.max() < 3.0, method



def _coulomb(s):
    """x'' = -x - sign(x') / 10, x(0) = 1, x'(0) = 0 on [0, 3 pi]: half periods about
    +-1/10 whose amplitude falls by 1/5 each (x' = 0 at k pi, where f jumps)."""
    k = np.minimum(np.floor(s / np.pi), 2)
    return (-1.0) ** k * (0.1 + (0.9 - 0.2 * k) * np.cos(s - k * np.pi))


def _heaviside(s):
    """u' = cos t + Heaviside(u - 1/2) u, u(0) = 0: sin t up to pi / 6, then growing."""
    c = (1 + np.sqrt(3)) / 4 * np.exp(-np.pi / 6)
    return np.where(s < np.pi / 6, np.sin(s), c * np.exp(s) + (np.sin(s) - np.cos(s)) / 2)


@pytest.mark.parametrize("method", ["cG(2)", "cG(3)", "cG(4)", "mcG(3)"])
@pytest.mark.parametrize("case", ["coulomb", "heaviside"])
def test_dense_cg_across_a_state_switch_reads_f_on_the_elements_branch(method, case, tmp_path):
    # the solve restarts at each crossing of the switch, so end nodes sit on it, where the
    # original f takes either branch by rounding: the element polynomial used instead was
    # 10-59 x the tolerance inside (cG(2), cG(3), mcG(3) at 1e-8), the ends within 0.5 x
    x, v = sp.symbols("x v")
    if case == "coulomb":
        rhs, u0, T, exact = {x: v, v: -x - sp.sign(v) / 10}, [1.0, 0.0], 3 * np.pi, _coulomb
    else:
        rhs, u0, T = {x: sp.cos(dn.t) + sp.Heaviside(x - sp.Rational(1, 2)) * x, v: -v}, \
            [0.0, 1.0], 2.0
        exact = _heaviside
    tolerance = 1e-8
    sol = dn.solve(dn.ODE(rhs, u0=u0, T=T), method=method, tolerance=tolerance)
    times = np.linspace(0.0, T, 4001)
    error = np.abs(sol(times)[0] - exact(times)) / (tolerance * np.maximum(np.abs(exact(times)), 1))
    assert sol.stats["state switches"] >= 1
    assert error.max() < 2.0
    sampled = dn.solve(dn.ODE(rhs, u0=u0, T=T), method=method, tolerance=tolerance,
                       sample_times=times, dense_output=False)
    np.testing.assert_array_equal(sampled.y, sol(times))  # (the samples read f alike)
    path = tmp_path / "run.h5"  # (and a history on file, which keeps the branches)
    dn.solve(dn.ODE(rhs, u0=u0, T=T), method=method, tolerance=tolerance, dense_output=path)
    loaded = dn.load_solution(path)
    np.testing.assert_array_equal(loaded(times), sol(times))
    loaded.close()


# --- dense output of multi-adaptive mdG(q): the collocation polynomial per component ---

@pytest.fixture(scope="module")
def fast_slow():
    """A strongly coupled fast-slow pair (eigenvalues -1, -1999) and a slow rotation driving
    it, with its reference at 121 times (scipy Radau, rtol 1e-12)."""
    a, b, c, d = sp.symbols("a b c d")
    ode = dn.ODE({a: -1000 * a + 999 * b + sp.sin(c), b: 999 * a - 1000 * b, c: d, d: -c},
                 u0=[1.0, 0.0, 0.0, 1.0], T=10.0)
    times = np.linspace(0.0, 10.0, 121) + 10.0 / 240  # (between the samples: inside elements)
    times = times[times < 10.0]
    reference = solve_ivp(lambda t, u: [-1000 * u[0] + 999 * u[1] + np.sin(u[2]),
                                        999 * u[0] - 1000 * u[1], u[3], -u[2]],
                          (0.0, 10.0), ode.u0, method="Radau", rtol=1e-12, atol=1e-14,
                          t_eval=times)
    return ode, times, reference.y


@pytest.mark.parametrize("q", [1, 2, 3])
def test_dense_mdg_interior_error_as_mono_dg(fast_slow, q):
    # inside elements mdG(q)'s plain element polynomials were 4.0-20 x mono dG(q)'s
    # collocation polynomials under the same jump test (sol._galerkin of dG(q)) here
    # (tolerance 1e-6); each component's collocation polynomial 0.7-1.2 x
    ode, times, exact = fast_slow
    scale = 1e-6 * (1 + np.abs(exact).max(axis=1))[:, None]
    multi, mono = (dn.solve(ode, f"{m}dG({q})", tolerance=1e-6) for m in ("m", ""))
    errors = [np.max(np.abs(values - exact) / scale)
              for values in (multi(times), mono._galerkin(times))]
    assert errors[0] < 2 * errors[1], f"mdG({q}) {errors[0]:.3g}, dG({q}) {errors[1]:.3g}"


@pytest.mark.parametrize("method", ["mdG(1)", "mdG(2)", "mdG(3)", "mcG(2)", "mcG(3)"])
def test_dense_multi_every_reader_agrees_and_keeps_the_ends(fast_slow, method, tmp_path,
                                                            monkeypatch):
    # element ends are each component's end node values bitwise; the mixed history, its
    # joined elements and a stored history give the same dense values bitwise, and differ
    # from the Galerkin polynomials inside. The samples of dense_output=False (the history
    # in many chunks, a long element of one component stored chunks after the others'
    # around it) are the same values bitwise (they were the values without f, 10 x the
    # tolerance apart)
    import sys

    from dolfinode.solution import _evaluate_components, dense_rule

    ode, times, _ = fast_slow
    sol = dn.solve(ode, method, tolerance=1e-5, sample_times=times)
    expected = sol(times)
    monkeypatch.setattr(sys.modules["dolfinode.solve"], "_CHUNK_LIMIT", 64)
    sampled = dn.solve(ode, method, tolerance=1e-5, sample_times=times, dense_output=False)
    stored = dn.solve(ode, method, tolerance=1e-5, dense_output=str(tmp_path / "run.h5"))
    np.testing.assert_array_equal(sampled.y, expected)
    np.testing.assert_array_equal(stored(times), expected)
    np.testing.assert_array_equal(dn.load_solution(tmp_path / "run.h5")(times), expected)
    ptr, t_start, t_end, values = sol.elements()  # (joins a mixed history)
    np.testing.assert_array_equal(sol(times), expected)
    for i in range(ode.N):
        ends = t_end[ptr[i]:ptr[i + 1]]
        np.testing.assert_array_equal(sol(ends)[i], values[ptr[i]:ptr[i + 1], -1])
    galerkin = np.empty((times.size, ode.N)).T
    _evaluate_components(ptr, t_start, t_end, values, sol.method.nodes,
                         sol.method.barycentric_weights, dense_rule(sol.method, dense=False),
                         ode.t0, ode.u0, times, galerkin)
    assert np.mean(galerkin != expected) > 0.25  # (the stiff pair's elements: U)


@pytest.mark.parametrize("method", ["mdG(2)", "mcG(2)"])
def test_dense_multi_values_kept_between_calls_are_those_of_a_fresh_solution(fast_slow,
                                                                            method):
    # a solution keeps what its elements read from call to call (solution.element_cache):
    # scalar calls, a vector call after them and a fresh solution give the same bits, and
    # new elements (a reader's) are read anew
    import pickle

    ode, times, _ = fast_slow
    sol = dn.solve(ode, method, tolerance=1e-5)
    ptr, t_start, t_end, values = sol.elements()
    fresh = dn.Solution.grouped(ode, sol.method, ptr, t_start, t_end, values, {}, 11)
    expected = fresh(times)
    scalars = np.array([sol(t) for t in times]).T
    np.testing.assert_array_equal(scalars, expected)
    np.testing.assert_array_equal(sol(times), expected)
    sol.values = values * (1 + 1e-3)
    moved = dn.Solution.grouped(ode, sol.method, ptr, t_start, t_end, sol.values, {}, 11)
    np.testing.assert_array_equal(sol(times), moved(times))
    assert "_element_cache" not in pickle.loads(pickle.dumps(sol)).__dict__


@pytest.mark.parametrize("method", ["cG(2)", "mcG(2)"])
def test_values_at_t0_and_T_alone_are_those_of_the_dense_evaluation(method):
    # sol(t0) and sol(T) alone skip the dense correction (and, mono-adaptive, sol(T) reads
    # the last nodal values): the same bits as where times inside (t0, T) come with them
    ode = _harmonic(5.0)
    sol = dn.solve(ode, method=method, tolerance=1e-6)
    with_inside = sol(np.array([0.0, 2.5, 5.0]))
    np.testing.assert_array_equal(sol(0.0), with_inside[:, 0])
    np.testing.assert_array_equal(sol(5.0), with_inside[:, 2])
    np.testing.assert_array_equal(sol([5.0, 5.0]), with_inside[:, [2, 2]])


def test_the_dense_values_announce_their_first_compile(monkeypatch):
    """cG(q)'s, dG(q)'s and the multi-adaptive dense values compile for 2-7 s on their first
    call: each is run under the compile notice (``first_use``) with its own routine."""
    from dolfinode import solution

    seen = []
    real = solution.first_use

    def recording(dispatcher, what, seconds):
        seen.append(dispatcher.py_func.__name__)
        return real(dispatcher, what, seconds)

    monkeypatch.setattr(solution, "first_use", recording)
    u, v = sp.symbols("u v")
    ode = dn.ODE({u: v, v: -u}, u0=[1.0, 0.0], T=1.0)
    for method, routine in (("cG(2)", "_evaluate_cg"), ("dG(2)", "_evaluate_dg"),
                            ("mcG(2)", "_correct_multi")):
        sol = dn.solve(ode, method=method, tolerance=1e-4)
        seen.clear()
        sol(0.5)
        assert set(seen) == {routine}, method


_u, _v, _w = sp.symbols("u v w")


@pytest.mark.parametrize(("rhs", "u0", "T", "method", "tol"), [
    # u follows sin(v)^3 (main: dG(1) at 1e-4 221 x the tolerance inside, dG(2) at 1e-6 42 x)
    ({_u: -800 * (_u - sp.sin(_v) ** 3), _v: 1 - _v / 5 + _u / 10}, [0.0, 0.0], 6.0, "dG(1)",
     1e-4),
    ({_u: -800 * (_u - sp.sin(_v) ** 3), _v: 1 - _v / 5 + _u / 10}, [0.0, 0.0], 6.0, "dG(2)",
     1e-6),
    # u follows w v (main: 17 x)
    ({_u: -2000 * (_u - _w * _v), _v: _u - _v, _w: 0.3 - _w / 10}, [0.0, 1.0, 0.5], 5.0,
     "dG(2)", 1e-6),
], ids=["cubic-dG(1)", "cubic-dG(2)", "product-dG(2)"])
def test_dg_a_component_stiff_on_its_element_is_accurate_inside(rhs, u0, T, method, tol):
    """A component stiff on the shared step (-k J_ii >> 1) has dG(q)'s nodes on its
    quasi-steady state; sol(t) between them takes the quasi-steady value W
    (solution._quasi_steady_dg), not the state's interpolant: within 10 x the tolerance
    inside, against scipy's Radau at 1e-12 (the slow components read u at the stages only
    and are accurate either way)."""
    f = sp.lambdify((dn.t, list(rhs)), list(rhs.values()))
    times = np.linspace(0.0, T, 4001)
    exact = solve_ivp(f, (0.0, T), u0, method="Radau", rtol=1e-12, atol=1e-14,
                      t_eval=times).y
    sol = dn.solve(dn.ODE(rhs, u0=u0, T=T), method, tolerance=tol)
    assert np.max(np.abs(sol(times) - exact) / np.maximum(1.0, np.abs(exact))) < 10 * tol


def test_dg_a_component_tied_to_a_faster_one_keeps_its_value():
    """ROBER's y1 is stiff on late steps by its diagonal (-k J_11 ~ 120) but tied to y2 and
    y3 (y1 + y2 + y3 = 1): one Newton step of its own equation moves it alone (61 x the
    tolerance inside, dG(2) at 1e-6), so it keeps its value (solution._evaluate_dg's
    fast-mode test): within 10 x inside on a log grid."""
    problem = problems.rober()
    ode, tol = problem.ode, 1e-6
    lowered = lower(ode)
    times = np.concatenate(([0.0], np.logspace(-6, np.log10(problem.T), 2000)))
    exact = solve_ivp(lambda t, y: lowered.f(np.ascontiguousarray(y), t), (0.0, problem.T),
                      ode.u0, method="Radau", rtol=1e-12, atol=1e-20, t_eval=times).y
    sol = dn.solve(ode, "dG(2)", tolerance=tol, absolute_tolerance=problem.atol_ratio * tol)
    error = np.abs(sol(times) - exact) / (tol * (problem.atol_ratio + np.abs(exact)))
    assert error.max() < 10
