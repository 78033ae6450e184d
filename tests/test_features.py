"""Narrow features of f(t) found before the solve (dolfinode/features.py)."""
import math

import mpmath
import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode import features
from dolfinode.features import enclose, narrow_features

u, v = sp.symbols("u v")
a = sp.Symbol("a")
t = dn.t
T = 10.0


def _gauss(height, centre, width):
    """(pulse, its integral over [0, T])."""
    integral = height * width * math.sqrt(math.pi) / 2 * (
        math.erf((T - centre) / width) + math.erf(centre / width))
    return height * sp.exp(-((t - centre) / width) ** 2), integral


def _sech2(height, centre, width):
    integral = height * width * (math.tanh((T - centre) / width) + math.tanh(centre / width))
    return height / sp.cosh((t - centre) / width) ** 2, integral


#: name -> (u' free of u, exact u(T) from u(0) = 0, parameters)
PULSES = {
    "gauss 0.05 at 6": (*_gauss(20.0, 6.0, 0.05), None),
    "gauss 1e-3 at 0.37": (*_gauss(5.0, 0.37, 1e-3), None),
    "gauss 1e-5 at 9.9": (*_gauss(1e4, 9.9, 1e-5), None),
    "sech2 1e-4 at 3.3": (*_sech2(1e3, 3.3, 1e-4), None),
    # sympy folds exp(-1e4 (t - 3)) into 6.8e13028 exp(-1e4 t), beyond double range
    "step 1e-4 at 3": (1 / (1 + sp.exp(-1e4 * (t - 3))), T - 3.0, None),
    "window 1e-4 at 6": (sp.Piecewise((1e4, (t > 6) & (t < 6.0001)), (0, True)), 1.0, None),
    "a x gauss 1e-3 at 2": (a * _gauss(1.0, 2.0, 1e-3)[0], 3e3 * _gauss(1.0, 2.0, 1e-3)[1],
                            {a: 3e3}),
}


@pytest.mark.parametrize("case", list(PULSES))
@pytest.mark.parametrize("method", ["cG(1)", "dG(1)", "mcG(2)"])
@pytest.mark.parametrize("tol", [1e-2, 1e-4])
def test_pulse_within_tolerance(case, method, tol):
    """u' = pulse beside a slow v' = -v: without the features every method stepped over the
    pulse (u(T) = 0) at loose tolerances, without a warning."""
    pulse, exact, params = PULSES[case]
    ode = dn.ODE({u: pulse, v: -v}, u0=[0.0, 1.0], T=T, params=params)
    sol = dn.solve(ode, method=method, tolerance=tol)
    assert abs(sol.y[0, -1] - exact) <= 10 * tol * max(1.0, abs(exact))


@pytest.mark.parametrize("method", ["cG(1)", "dG(1)", "mcG(2)"])
def test_pulse_times_the_state(method):
    """u' = -u (1 + 20 exp(-((t - 6)/0.05)^2)): the factor free of u is searched."""
    pulse, integral = _gauss(20.0, 6.0, 0.05)
    ode = dn.ODE({u: -u * (1 + pulse)}, u0=[1.0], T=T)
    sol = dn.solve(ode, method=method, tolerance=1e-3)
    assert sol.stats["narrow features"] == 1
    exact = math.exp(-T - integral)
    assert abs(sol.y[0, -1] - exact) <= 10 * 1e-3


@pytest.mark.parametrize("width", [1e-2, 1e-4, 1e-5])
@pytest.mark.parametrize("centre", [0.5, 4.123456, 9.75])
def test_feature_contains_the_peak(width, centre):
    """Pulses down to 1e-6 (T - t0) are found, and lie inside their feature with a largest
    step below their width."""
    ode = dn.ODE({u: -u + sp.exp(-((t - centre) / width) ** 2)}, u0=[1.0], T=T)
    features = narrow_features(ode)
    assert len(features) == 1
    assert features.start[0] < centre - 2 * width and centre + 2 * width < features.end[0]
    assert features.step[0] < 2 * width  # (the width at 1/e of the peak)


@pytest.mark.parametrize("forcing", [sp.sin(t), sp.sin(100 * t), sp.sin(1e4 * t),
                                     t**3 - 2 * t, sp.exp(-t / 3), sp.Piecewise((1, t < 5),
                                                                             (0, True))])
def test_smooth_forcing_has_no_features(forcing):
    """Periodic and slow forcing has no features: no breakpoints are added (a jump in t
    keeps its own breakpoint; a sine fast over [t0, T] bounds the steps, next test)."""
    ode = dn.ODE({u: -u + forcing}, u0=[1.0], T=T)
    assert len(narrow_features(ode)) == 0
    sol = dn.solve(ode, method="cG(1)", tolerance=1e-3, estimate_global_error=False)
    assert sol.stats.get("narrow features", 0) == 0
    assert sol.stats.get("breakpoints", 0) == (1 if forcing.has(sp.Piecewise) else 0)


@pytest.mark.parametrize("method", ["cG(1)", "cG(2)", "dG(2)", "mcG(2)"])
def test_a_fast_sine_bounds_the_steps(method):
    """u' = -u + sin(1e4 t) on [0, 2]: steps of several periods evaluate the sine at a few
    points each (aliased), and the runs ended 19-98 x the tolerance off (cG(1) unwarned at
    19 x). The steps are bounded by 1 / omega, the sixth of a period, and the error lands
    within the tolerance; a forcing whose effect is below atol, or a maximum_time_step
    given, is not bounded."""
    W = 1e4
    ode = dn.ODE({u: -u + sp.sin(W * t)}, u0=[1.0], T=2.0)
    assert narrow_features(ode).step_cap(np.array([1e-3]), 2.0) == pytest.approx(1 / W)
    exact = (1 + W / (1 + W**2)) * math.exp(-2.0) + (math.sin(2 * W) - W * math.cos(2 * W)) / (
        1 + W**2)
    sol = dn.solve(ode, method, tolerance=1e-3, estimate_global_error=False)
    assert abs(sol(2.0)[0] - exact) <= 1e-3 * (1 + abs(exact))
    assert sol.stats["oscillation step bound"] == pytest.approx(1 / W)
    weak = dn.ODE({u: -u + 1e-12 * sp.sin(W * t)}, u0=[1.0], T=2.0)
    slabs = sol.stats["time slabs"]
    assert slabs >= 2.0 * W
    assert dn.solve(weak, method, tolerance=1e-3).stats["time slabs"] < slabs / 10
    given = dn.solve(ode, method, tolerance=1e-3, maximum_time_step=2.0,
                     estimate_global_error=False)
    assert given.stats["time slabs"] < slabs / 10
    assert "oscillation step bound" not in given.stats


def test_a_solver_bounds_the_steps_by_each_calls_frequency():
    """The bound follows the frequency parameter of each Solver call, as a fresh solve."""
    w = sp.Symbol("w")
    ode = dn.ODE({u: -u + sp.sin(w * t)}, u0=[1.0], T=2.0, params={w: 1.0})
    solver = dn.Solver(ode, "cG(2)", tolerance=1e-3)
    for omega in (1.0, 1e4, 1.0, 3e3):
        sol = solver.solve(params={w: omega})
        fresh = dn.solve(dn.vary(ode, {w: omega}), "cG(2)", tolerance=1e-3)
        np.testing.assert_array_equal(sol.t_start, fresh.t_start)
        assert (sol.stats["time slabs"] > 1000) == (omega > 1e3)


def test_two_pulses_and_forcing():
    """Features of separate terms, beside a periodic forcing, each with its own edges."""
    first, second = _gauss(1.0, 2.0, 1e-3), _gauss(1.0, 7.0, 1e-2)
    ode = dn.ODE({u: sp.sin(t) + first[0] + second[0]}, u0=[0.0], T=T)
    features = narrow_features(ode)
    assert len(features) == 2
    assert features.end[0] < 2.5 < features.start[1]
    sol = dn.solve(ode, method="dG(1)", tolerance=1e-4)
    exact = 1 - math.cos(T) + first[1] + second[1]
    assert abs(sol.y[0, -1] - exact) <= 10 * 1e-4 * abs(exact)
    assert sol.stats["breakpoints"] == 4


def test_new_parameter_values_search_anew():
    """A Solver whose parameter moves the pulse (or narrows it into a feature) finds the
    features of each call's values."""
    c, w = sp.symbols("c w")
    ode = dn.ODE({u: sp.exp(-((t - c) / w) ** 2), v: -v}, u0=[0.0, 1.0], T=T,
                 params={c: 6.0, w: 1.0})
    solver = dn.Solver(ode, method="cG(2)", tolerance=1e-4)
    for centre, width in [(6.0, 1.0), (3.3, 1e-4), (8.1, 1e-3), (6.0, 1.0)]:
        sol = solver.solve(params={c: centre, w: width})
        exact = width * math.sqrt(math.pi) / 2 * (math.erf((T - centre) / width)
                                                  + math.erf(centre / width))
        assert abs(sol.y[0, -1] - exact) <= 10 * 1e-4 * max(1.0, exact)
        assert sol.stats.get("narrow features", 0) == (width < 1e-2)


def test_autonomous_system_untouched():
    ode = dn.ODE({u: -u + v, v: -v}, u0=[1.0, 1.0], T=T)
    assert len(narrow_features(ode)) == 0
    sol = dn.solve(ode, method="cG(1)")
    assert "narrow features" not in sol.stats


def test_term_without_bounds_is_listed():
    """atan2 has no interval bounds here: its term is listed as unbounded, not searched."""
    ode = dn.ODE({u: -u + sp.atan2(sp.sin(t), sp.cos(t) + 2)}, u0=[1.0], T=T)
    features = narrow_features(ode)
    assert len(features) == 0
    assert features.unbounded == [sp.atan2(sp.sin(t), sp.cos(t) + 2)]


#: Expressions of t whose bounds are checked against samples.
BOUNDED = [sp.exp(-((t - 3) / 0.1) ** 2), sp.sin(7 * t) * sp.cos(t) + t**2,
           1 / sp.cosh(3 * t - 2) ** 2, sp.log(1 + t) / (2 + sp.sin(t)), sp.sqrt(t + 1) * t**-2,
           sp.tanh(t - 4) * sp.erf(t - 5) + sp.erfc(t) + sp.atan(t) + sp.asinh(t),
           sp.tan(t), sp.exp(t) ** sp.Rational(3, 2) - 2**t,
           sp.Max(sp.sin(t), t / 3 - 1) + sp.Min(t, sp.cos(2 * t)) * sp.Heaviside(t - 4)]


@pytest.mark.parametrize("expr", BOUNDED, ids=str)
def test_enclosure_holds_the_values(expr):
    """The bounds of enclose contain expr at every sample of each piece, and tighten as the
    pieces shrink."""
    rng = np.random.default_rng(3)
    lo = np.sort(rng.uniform(0.1, 9.0, 200))
    widths = []
    for width in (1.0, 1e-2, 1e-4):
        hi = lo + width
        low, high = enclose(expr, lo, hi)
        f = sp.lambdify(t, expr, ["scipy", "numpy"])
        samples = f(lo[:, None] + np.linspace(0, 1, 33) * width)
        finite = np.isfinite(samples).all(axis=1)
        rounding = 1e-12 * (1 + abs(samples[finite]))
        assert np.all(low[finite, None] <= samples[finite] + rounding)
        assert np.all(samples[finite] <= high[finite, None] + rounding)
        widths.append(np.median(high - low))
    assert widths[2] < widths[1] < widths[0]


@pytest.mark.parametrize("method", ["cG(1)", "dG(1)", "mcG(2)"])
def test_global_error_estimate_across_features(method):
    """The breakpoints of a feature split a smooth f: the estimate of the error at T holds
    across them (u(T) against the closed form, in the tolerance's scale 1 + |u(T)|)."""
    pulse, integral = _gauss(20.0, 6.0, 0.05)
    ode = dn.ODE({u: pulse, v: -v}, u0=[0.0, 1.0], T=T)
    sol = dn.solve(ode, method=method, tolerance=1e-5, estimate_global_error=True)
    assert sol.stats["narrow features"] == 1
    error = abs(sol.y[0, -1] - integral) / (1 + integral)
    assert 0.5 <= sol.stats["global error estimate"] / error <= 2


def test_kept_solver_sees_a_narrowed_pulse():
    """dn.solve keeps a prepared solver for repeated calls (dolfinode/kept.py): a pulse
    narrowed by a new parameter value on the declaration is found at the next call."""
    w = sp.Symbol("w")
    ode = dn.ODE({u: sp.exp(-((t - 6) / w) ** 2), v: -v}, u0=[0.0, 1.0], T=T, params={w: 1.0})
    for width in (1.0, 1.0, 1.0, 1e-4):
        ode.params[w] = width
        sol = dn.solve(ode, method="dG(1)", tolerance=1e-4)
    assert sol.stats["narrow features"] == 1
    assert abs(sol.y[0, -1] - 1e-4 * math.sqrt(math.pi)) <= 10 * 1e-4


def test_a_train_of_many_pulses_warns():
    """A term with more narrow pulses than MAX_FEATURES (317 spikes of width ~0.01 on
    [0, 1000]) is not split at each: a ToleranceWarning names it and what to give."""
    spikes = sp.exp(-1e4 * sp.sin(t) ** 2)
    ode = dn.ODE({u: -u + spikes}, u0=[1.0], T=1000.0)
    with pytest.warns(dn.ToleranceWarning, match="317 narrow features.*maximum_time_step"):
        features = narrow_features(ode)
    assert len(features) == 0
    # on [0, 100] the same term has 32 of them, each a feature
    assert len(narrow_features(dn.ODE({u: -u + spikes}, u0=[1.0], T=100.0))) == 32


def test_time_symbol_compared_by_value():
    """sympy's symbol cache is bounded: after many expressions, Symbol("t", real=True) can be
    a second object equal to dn.t. The search reads t by value."""
    fresh = sp.Symbol.__xnew__(sp.Symbol, "t", real=True)
    assert fresh == t and fresh is not t
    pulse = sp.exp(-((fresh - 6) / 1e-4) ** 2)
    ode = dn.ODE({u: -u + pulse}, u0=[1.0], T=T)
    assert len(narrow_features(ode)) == 1
    low, high = enclose(pulse, np.array([5.9]), np.array([6.1]))
    assert low[0] <= 0.0 and high[0] == 1.0


@pytest.mark.parametrize("method", ["cG(2)", "mcG(2)"])
def test_a_pulse_in_a_template_term_is_found(method):
    """A template term 20 exp(-((t - 6)/0.05)^2) was not searched: u(10) came out 4.6e-216
    (cG(2)) and 1.7e-90 (mcG(2)) instead of 1.77 at tolerance 1e-4, without a warning.
    Sub-expressions free of the slots and of the cells' parameters are searched: a pulse
    times a cell parameter is found, one centred at a cell parameter is not."""
    x, y, c = sp.symbols("x y c")
    pulse = 20 * sp.exp(-((dn.t - 6) / 0.05) ** 2)
    template = dn.Template(slots=(x, y), terms={x: pulse, y: -y}, indices=np.array([[0, 1]]))
    ode = dn.TemplateODE([template], u0=[0.0, 1.0], T=10.0)
    assert len(narrow_features(ode)) == 1
    sol = dn.solve(ode, method, tolerance=1e-4)
    assert sol(10.0)[0] == pytest.approx(math.sqrt(math.pi), rel=1e-3)
    centred = 20 * sp.exp(-((dn.t - c) / 0.05) ** 2)
    for term, found in [(c * pulse, 1), (centred, 0)]:
        per_cell = dn.Template(slots=(x,), terms={x: term}, indices=np.array([[0]]),
                               params=(c,), values=np.array([[6.0]]))
        assert len(narrow_features(dn.TemplateODE([per_cell], u0=[0.0], T=10.0))) == found


#: name -> (state-free term, T, its singular points, exact integral over [0, T])
SINGULAR = {
    "sqrt|t - 1|": (sp.sqrt(sp.Abs(t - 1)), 2.0, (1.0,), 4 / 3),
    "|t - 1|^(1/4)": (sp.Abs(t - 1) ** sp.Rational(1, 4), 2.0, (1.0,), 1.6),
    "|t - 1|^(3/2)": (sp.Abs(t - 1) ** sp.Rational(3, 2), 2.0, (1.0,), 0.8),
    "((t - 0.7)^2)^(1/3)": (((t - 0.7) ** 2) ** sp.Rational(1, 3), 1.0, (0.7,),
                            0.6 * (0.7 ** (5 / 3) + 0.3 ** (5 / 3))),
    "sqrt(1 - t) at T": (sp.sqrt(1 - t), 1.0, (1.0,), 2 / 3),
    # a constant sympy keeps as pi
    "sqrt|t - pi/2|": (sp.sqrt(sp.Abs(t - sp.pi / 2)), 2.0, (math.pi / 2,),
                       2 / 3 * ((math.pi / 2) ** 1.5 + (2 - math.pi / 2) ** 1.5)),
    # the breakpoint fl(pi/2) is below the root: cos's continuation -cos is < 0 there
    "sqrt|cos t|": (sp.sqrt(sp.Abs(sp.cos(t))), 2.0, (math.pi / 2,),
                    float(mpmath.quad(lambda s: mpmath.sqrt(abs(mpmath.cos(s))),
                                      [0, mpmath.pi / 2, 2]))),
    "sqrt(max(cos t, 0))": (sp.sqrt(sp.Max(sp.cos(t), 0)), 2.0, (math.pi / 2,),
                            float(mpmath.quad(lambda s: mpmath.sqrt(mpmath.cos(s)),
                                              [0, mpmath.pi / 2]))),
}


@pytest.mark.parametrize("case", list(SINGULAR))
def test_singular_points_are_found(case):
    h, end, points, _ = SINGULAR[case]
    features = narrow_features(dn.ODE({u: -u + h}, u0=[1.0], T=end))
    np.testing.assert_allclose(features.singular, points, atol=1e-8)


@pytest.mark.parametrize("h", [sp.sin(t), sp.Abs(t - 1), sp.sqrt(t**2 - 2 * t + 1.0001),
                               sp.exp(-((t - 1) / 1e-3) ** 2), sp.Heaviside(t - 1)])
def test_smooth_pieces_have_no_singular_points(h):
    assert narrow_features(dn.ODE({u: -u + h}, u0=[1.0], T=2.0)).singular == ()


@pytest.mark.parametrize("case", list(SINGULAR))
@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "dG(2)"])
@pytest.mark.parametrize("tol", [1e-6, 1e-8])
def test_derivative_singularity_within_tolerance(case, method, tol):
    """A step that ends at a point where f(t)'s derivatives blow up is far from a polynomial
    and the step control, which sees only polynomials, accepted it: 15-280 x the tolerance
    at T, and no warning where |t - 1| made the solve piecewise (no estimate at T)."""
    h, end, points, exact = SINGULAR[case]
    sol = dn.solve(dn.ODE({u: h}, u0=[0.0], T=end), method=method, tolerance=tol)
    assert abs(sol.y[0, -1] - exact) <= 10 * tol * max(1.0, abs(exact))
    assert sol.stats["singular points"] == 1
    # no step near the point longer than twice GRADING times its distance to it
    s, starts, k = points[0], *sol.time_steps()
    near = np.maximum(abs(starts - s), abs(starts + k - s))
    inside = near < end / features.RINGS_FROM
    assert np.all(k[inside] <= 2 * features.GRADING * near[inside] + 1e-7 * end)


def test_singular_factor_of_the_state_within_tolerance():
    """u' = -|t - 1|^(1/4) u: the factor free of u is searched, u = exp(-1.6) at T = 2."""
    sol = dn.solve(dn.ODE({u: -(sp.Abs(t - 1) ** sp.Rational(1, 4)) * u}, u0=[1.0], T=2.0),
                   method="dG(2)", tolerance=1e-8)
    assert abs(sol.y[0, -1] - math.exp(-1.6)) <= 1e-7
