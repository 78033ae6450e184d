"""The subgrid models: the pattern of the affine model and its least-squares fit."""
import warnings

import numpy as np
import pytest
import sympy as sp
from scipy import sparse

import dolfinode as dn
from dolfinode.bench.problems import seed_model
from dolfinode.compile import lower
from dolfinode.modeling.reduced import affine_pattern, fit_affine, inactive_components


def test_affine_pattern_reaches_through_the_inactive_components():
    # 0, 1 active; 2 -> 3 -> 4 inactive chain: f_0 depends on u_2, u_4 on u_1
    J = sparse.csr_matrix(np.array([[1, 0, 1, 0, 0],
                                    [0, 1, 0, 0, 0],
                                    [0, 0, 0, 1, 0],
                                    [0, 0, 0, 0, 1],
                                    [0, 1, 0, 0, 0]], dtype=float))
    rows, cols = affine_pattern(J, np.array([True, True, False, False, False]))
    assert list(zip(rows, cols)) == [(0, 1)]  # J_AA's own entries are not in it


def test_fit_affine_recovers_a_linear_dependence_along_the_windows():
    pattern = (np.array([0, 0]), np.array([1, 2]))
    G = np.array([2.0, -1.0])
    u = [np.array([5.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 1.0, 1.0]),
         np.array([0.0, 0.0, 0.0])]
    g = [np.array([G @ uk[1:], 0.0, 0.0]) for uk in u]
    np.testing.assert_allclose(fit_affine(pattern, u, g), G, rtol=1e-10)
    assert not fit_affine(pattern, u[:1], g[:1]).any()  # one window: constant model
    # windows along one direction (1, 1) up to noise below AFFINE_RCOND: the minimum-norm
    # slope along it, G (1, 1)/2 on both entries, not a noise-driven second direction
    u = [np.array([0.0, 1.0, 1.0 + 1e-3]), np.array([0.0, 2.0, 2.0]), np.zeros(3)]
    g = [np.array([G @ uk[1:], 0.0, 0.0]) for uk in u]
    np.testing.assert_allclose(fit_affine(pattern, u, g), [0.5, 0.5], atol=1e-3)


def test_fast_pairs_are_inactivated_together():
    """Two fast oscillators (omega 100 and 200) and a slow one: a fast velocity whose average
    moves keeps its position active too; the other pair is inactivated; the slow pair never."""
    x, v = sp.symbols("x0:3"), sp.symbols("v0:3")
    rhs = {}
    for i, w2 in enumerate((1.0, 1e4, 4e4)):
        rhs[x[i]] = v[i]
        rhs[v[i]] = -w2 * x[i] + (x[0] if i else 0)
    ode = dn.ODE(rhs, u0=[1.0] * 6, T=1.0)
    compiled = lower(ode)
    index = {s: i for i, s in enumerate(ode.states)}
    drift = np.zeros(ode.N)
    drift[index[v[1]]] = 1.0  # the average of v1 moves
    inactive = inactive_components(ode, compiled, 0.1, drift, 0.1)
    assert {s for s in ode.states if inactive[index[s]]} == {x[2], v[2]}
    drift[index[v[2]]] = 1.0
    with pytest.raises(ValueError, match="average_length = 0.1 is too short"):
        inactive_components(ode, compiled, 0.1, drift, 0.1)


def test_too_short_average_length_is_a_clear_error():
    """The seed model with tau = 1.6 fast periods: x2 was inactivated alone, x2' drifted and
    the reduced model blew up (SolverError at maximum_steps); now a ValueError says why."""
    problem = seed_model(1e4, T=10.0)
    with pytest.raises(ValueError, match="average_tolerance"):
        dn.solve(problem.ode, method="cG(2)", tolerance=1e-4, automatic_modeling=True,
                 average_length=10.0 / 100.0)


def test_relaxation_is_fast_for_the_relaxing_component_only():
    """Michaelis-Menten: J_sc J_cs ~ kappa > 0 is no oscillation, so s is slow (omega ~ 1)
    and c fast (omega = kappa (s + K)); c relaxes, the seed model's fast pair oscillates."""
    from dolfinode.bench.multiscale import michaelis_menten
    from dolfinode.modeling.reduced import component_frequencies, relaxing_components

    ode, _ = michaelis_menten(kappa=1e4)
    J = lower(ode).jacobian_matrix(ode.u0, 0.0)
    omega = component_frequencies(J)
    assert omega[0] == pytest.approx(1.0) and omega[1] == pytest.approx(2e4)
    assert list(relaxing_components(J, omega > 100)) == [False, True]
    seed = seed_model(1e4).ode
    J = lower(seed).jacobian_matrix(seed.u0, 0.0)
    np.testing.assert_allclose(component_frequencies(J), [1.0, 100.0, 1.0, 100.0])
    assert not relaxing_components(J, np.ones(4, dtype=bool)).any()


def test_manifold_rates_differentiate_the_constraint():
    """F = k (s - (s + K) c) = 0 along s' = r: c' = (1 - c) r / (s + K)."""
    from dolfinode.modeling.manifold import manifold_rates

    s, c, k, K, r = sp.symbols("s c k K r")
    rate, = manifold_rates((s, c), [k * (s - (s + K) * c)], [r, sp.S.Zero],
                           np.array([False, True]))
    assert sp.simplify(rate - (1 - c) * r / (s + K)) == 0


def test_default_average_length_looks_at_both_scales():
    """Seed model: |lambda| = 1 (slow) and sqrt(kappa) (fast). tau = 100 / sqrt(kappa) unless
    that exceeds 0.2 slow time units, then 0.2, but at least 30 fast time units."""
    from dolfinode.modeling.reduced import default_average_length

    for kappa, tau in [(1e4, 0.3), (1e5, 0.2), (1e6, 0.1)]:
        ode = seed_model(kappa).ode
        assert default_average_length(lower(ode), ode.u0, 0.0) == pytest.approx(tau, rel=1e-6)


def test_auto_checks_early_where_the_first_check_is_too_far_to_extrapolate():
    """The proportional class (y' = cos t - y x^2, x'' = -kappa x) at kappa = 1e10: the
    first check is 9000 half windows away, too far for the half windows' affine fit, and a
    constant g~ would leave an error of 2.2 on that span. "auto" checks early (rate x d^2 a
    tenth of the tolerance), rebuilds affine there, and is right without a warning against
    the averaged solution y-bar' = cos t - y-bar / 2 (x^2 averages to 1/2; O(kappa^-1/2))."""
    from dolfinode.bench.multiscale import proportional

    ode, _ = proportional(1e10)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = dn.solve(ode, method="cG(2)", tolerance=1e-4, automatic_modeling=True)
    assert not [w for w in caught if issubclass(w.category, dn.ModelingWarning)]
    model = sol.model
    assert model.early_check < model.spacing / 100 and model.affine
    assert model.control_points[0].time == pytest.approx(model.built[0] + model.early_check)
    assert model.control_points[0].rebuilt and len(model.built) == 2
    t = np.linspace(5.0, ode.T, 200)
    y_bar = 0.4 * np.cos(t) + 0.8 * np.sin(t) - 0.4 * np.exp(-t / 2)
    assert np.max(np.abs(sol(t)[0] - y_bar)) < 1e-3 * np.ptp(y_bar)  # measured 6.9e-6
