"""Automatic modeling is right or says it is not (issue 28): on four classes of multiscale
systems (dolfinode.bench.multiscale, scale separation 1e4), against the full model resolved by
scipy and averaged with the modeling kernel, the slow components are within 1e-2 of their
range, or a ModelingWarning fires whose estimate is at least the error; on the seed model,
whose reduced model is right, nothing fires."""
import warnings

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.bench import multiscale
from dolfinode.bench.problems import seed_model
from dolfinode.modeling.validity import OSCILLATION, unfollowed_rate

SETTINGS = {"method": "cG(2)", "tolerance": 1e-4, "automatic_modeling": True}
CLASSES = ("adiabatic", "michaelis_menten", "proportional")
#: The classes that come out right (measured max error / range: 1.6e-5 and 1.5e-5; the
#: adiabatic one, fast frequency depending on the slow state, with the flow-averaged model
#: that the default takes for it: 1.3e-9; it was off by 0.13 and warned).
RIGHT = CLASSES


def _model_warnings(caught):
    """The ModelingWarnings about the reduced model (not the one about the fast oscillation,
    a statement on the average against the pointwise solution)."""
    return [w for w in caught if issubclass(w.category, dn.ModelingWarning)
            and OSCILLATION not in str(w.message)]


@pytest.fixture(scope="module", params=CLASSES)
def modeled(request):
    """(ode, slow, solution, warnings, times, averaged reference) for one class."""
    ode, slow = multiscale.CLASSES[request.param]()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = dn.solve(ode, **SETTINGS)
    tau = sol.model.average_length
    times = np.linspace(3 * tau, ode.T, 120)
    stiff = request.param == "michaelis_menten"
    # (DOP853 at rtol 1e-9 is off by 7e-8 at T on the adiabatic class, where the flows of
    # degree 4 are within 2e-10)
    reference = multiscale.averaged_reference(ode, times, tau, "Radau" if stiff else "DOP853",
                                              rtol=1e-9 if stiff else 1e-11)
    fired = _model_warnings(caught)
    oscillation = [w for w in caught if OSCILLATION in str(w.message)]
    assert bool(oscillation) == (sol.stats["fast oscillation"] > SETTINGS["tolerance"])
    return request.param, ode, slow, sol, fired, times, reference


@pytest.mark.parametrize("tolerance", [1e-4, 1e-3])
def test_fast_oscillation_of_a_slow_component_warns_above_the_tolerance(tolerance):
    """y' = -y + x^2, x = cos(omega t): y differs from its average by about sin(2 omega t) /
    (4 omega) = 2.5e-4 at omega = 1e3 (the pointwise error, within the model's own): measured within 2 %,
    warned at tolerance 1e-4, not at 1e-3."""
    y, x, v = sp.symbols("y x v")
    omega = 1e3
    ode = dn.ODE({y: -y + x**2, x: v, v: -omega**2 * x}, u0=[0.0, 1.0, 0.0], T=4.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = dn.solve(ode, **dict(SETTINGS, tolerance=tolerance))
    t = np.linspace(3.0, 4.0, 20001)
    exact = 0.5 * (1 - np.exp(-t)) + 0.5 * (np.cos(2 * omega * t) + 2 * omega
                                            * np.sin(2 * omega * t) - np.exp(-t)) \
        / (1 + 4 * omega**2)
    pointwise = np.max(np.abs(sol(t)[0] - exact))
    assert sol.stats["fast oscillation"] == pytest.approx(1 / (4 * omega), rel=0.02)
    assert pointwise == pytest.approx(sol.stats["fast oscillation"], rel=0.1)
    assert not _model_warnings(caught)
    oscillation = [w for w in caught if OSCILLATION in str(w.message)]
    assert len(oscillation) == (pointwise > tolerance)
    if oscillation:
        assert "y oscillates" in str(oscillation[0].message)


def test_slow_components_right_or_warned_with_an_estimate_above_the_error(modeled):
    name, _ode, slow, sol, fired, times, reference = modeled
    U = sol(times)
    relative = max(np.max(np.abs(U[i] - reference[i])) / np.ptp(reference[i]) for i in slow)
    error_T = max(abs(U[i, -1] - reference[i, -1]) for i in slow)
    assert sol.model.estimate.total >= error_T
    if name in RIGHT:
        assert not fired and relative < 1e-3
    if not fired:
        assert relative < 1e-2
        return
    assert len(fired) == 1
    message = str(fired[0].message)
    assert "above the tolerance" in message or "exceeds the tolerance" in message
    assert sol.model.estimate.total >= error_T
    assert sol.stats["modeling error estimate"] == sol.model.estimate.total


def test_effectivity_in_each_slow_component(modeled):
    """modeling_error(goal) + |discretisation| >= 0.5 |U(T) - u-bar(T)| (measured effectivities
    of 5 to 40: the interpolated defect and |phi| make it a bound rather than an estimate)."""
    _, ode, slow, sol, _fired, _times, reference = modeled
    for i in slow:
        estimate = sol.model.modeling_error({ode.states[i]: 1.0})
        assert estimate.goal == "the goal"
        if sol.model.subgrid_model != "flow":  # (its estimate solves no dual)
            assert estimate.bound <= estimate.S0 * estimate.largest_defect * (1 + 1e-9)
        assert estimate.total >= 0.5 * abs(sol(ode.T)[i] - reference[i, -1])


def test_relative_defects_are_relative_to_a_scale_that_cannot_vanish():
    """On Michaelis-Menten max |g-bar| is ~1e-19 (c sits on its manifold); the defect is
    relative to max |g-bar| + tolerance (it was 1e13 relative to g-bar alone)."""
    ode, _ = multiscale.michaelis_menten()
    sol = dn.solve(ode, **SETTINGS)
    assert max(c.relative_defect for c in sol.model.control_points) < 1.0  # measured 0.05


def test_strict_raises_where_it_would_warn():
    """The adiabatic class with the constant/affine reduced model (off by 0.13, warned)."""
    ode, _ = multiscale.adiabatic()
    with pytest.raises(dn.SolverError, match="automatic modeling: the reduced model may not"):
        dn.solve(ode, strict=True, subgrid_model="affine", **SETTINGS)


def test_stiff_springs_of_moving_centres_raise_with_inactivation():
    """Fermi-Pasta-Ulam: every component is fast (the slow variables are the centres of the
    stiff springs, combinations of components); the averages move, so no component can be
    inactivated, and with a loose average_tolerance all would be: both raise for the
    constant model (the default takes the flow-averaged model, see test_flow.py)."""
    ode, _ = multiscale.fermi_pasta_ulam()
    with pytest.raises(ValueError, match="can inactivate none.*Fermi-Pasta-Ulam"):
        dn.solve(ode, subgrid_model="constant", **SETTINGS)
    with pytest.raises(ValueError, match="would inactivate every component"):
        dn.solve(ode, average_tolerance=1.0, subgrid_model="constant", **SETTINGS)


@pytest.mark.parametrize("kappa", [1e8, 1e18])
def test_seed_model_is_not_warned_and_its_estimate_bounds_the_error(kappa):
    """The seed model's reduced model is exact up to the averaging: no ModelingWarning, and
    the estimate of x1(T) lies above the error (measured 8.6e-6 against 4.7e-6)."""
    ode = seed_model(kappa, T=100.0).ode
    with warnings.catch_warnings():
        warnings.simplefilter("error", dn.ModelingWarning)
        sol = dn.solve(ode, **SETTINGS)
    assert sol.model.estimate.total < SETTINGS["tolerance"]
    assert not unfollowed_rate(sol.model).any()  # the fast amplitude is constant
    error = abs(sol(100.0)[0] - (1 - np.cos(100.0)) / 4)
    estimate = sol.model.modeling_error({ode.states[0]: 1.0})
    assert 0.5 * error <= estimate.total < 10 * SETTINGS["tolerance"]


@pytest.mark.parametrize("start", ["off the manifold", "on the manifold", "average_length 0.1"])
def test_relaxing_component_follows_its_slow_manifold(start):
    """Michaelis-Menten, eps = 1e-4: c is slaved to c = s / (s + K) (Newton at every segment
    start, the differentiated constraint between), not frozen; s is right within 1e-3 of its
    range, whether c starts on the manifold or not and with a long average (the substrate s
    was named fast there, and c frozen gave a staircase off by 0.1)."""
    K = 1.0
    ode, _ = multiscale.michaelis_menten(K=K)
    extra = {}
    if start == "on the manifold":
        ode = dn.vary(ode, {"u0": [1.0, 1.0 / (1.0 + K)]})
    elif start == "average_length 0.1":
        extra = {"average_length": 0.1}
    with warnings.catch_warnings():
        warnings.simplefilter("error", dn.ModelingWarning)
        sol = dn.solve(ode, **SETTINGS, **extra)
    _s, c = ode.states
    assert sol.model.slaved == (c,) and sol.model.inactive == (c,)
    tau = sol.model.average_length
    times = np.linspace(3 * tau, ode.T, 60)
    reduced = sol.model.reduced(times)
    np.testing.assert_allclose(reduced[1], reduced[0] / (reduced[0] + K), atol=1e-5)  # 1.8e-6
    reference = multiscale.averaged_reference(ode, times, tau, "Radau", rtol=1e-9)
    assert np.max(np.abs(reduced[0] - reference[0])) < 1e-3 * np.ptp(reference[0])


def _g_bar_after_restart(ode, u_start, tau):
    """g-bar of x1' (avg x2^2 / 2 - x2-bar^2 / 2) over the window [0, 2 tau] of the full model
    restarted from u_start (scipy DOP853), averaged with the modeling kernel about tau."""
    from scipy.integrate import solve_ivp

    from dolfinode.compile import lower
    from dolfinode.modeling import kernel_weights

    compiled = lower(ode)
    w = kernel_weights(2000)
    times = np.linspace(0.0, 2 * tau, w.size)
    x2 = solve_ivp(lambda t, u: compiled.f(u, t), (0.0, 2 * tau), u_start, method="DOP853",
                   rtol=1e-10, atol=1e-12, t_eval=times).y[1]
    return (x2**2 @ w - (x2 @ w) ** 2) / 2


def test_control_point_restart_does_not_depend_on_the_phase():
    """The seed model with x2'' = -kappa (1 + x1) x2: a fluctuation recorded at x1 = 0
    (amplitude 1) restarted at x1 = 0.3 at 8 phases of the fast orbit. Carried by
    adiabatic_scaling (action E / omega kept), g-bar is the same at every phase (spread
    < 1%) and equal to the adiabatic value 1 / (4 sqrt(1.3)); unscaled it depends on the
    phase."""
    from dolfinode.compile import lower
    from dolfinode.modeling.reduced import adiabatic_scaling

    ode, _ = multiscale.adiabatic(kappa=1e4)
    compiled, tau, omega = lower(ode), 0.3, 100.0
    slow_old, slow_new = np.zeros(4), np.array([0.3, 0.0, 0.0, 0.0])
    scaling = adiabatic_scaling(compiled.jacobian_matrix(slow_old, 0.0),
                                compiled.jacobian_matrix(slow_new, 0.0))
    g_scaled, g_raw = [], []
    for theta in np.linspace(0.0, np.pi, 8, endpoint=False):  # x2^2 has period pi in theta
        fluctuation = np.array([0.0, np.cos(theta), 0.0, -omega * np.sin(theta)])
        g_scaled.append(_g_bar_after_restart(ode, slow_new + scaling * fluctuation, tau))
        g_raw.append(_g_bar_after_restart(ode, slow_new + fluctuation, tau))
    assert np.ptp(g_scaled) < 0.01 * np.mean(g_scaled)
    assert np.mean(g_scaled) == pytest.approx(0.25 / np.sqrt(1.3), rel=0.01)
    assert np.ptp(g_raw) > 0.05 * np.mean(g_raw)


def test_a_damped_fast_oscillation_is_warned_with_an_estimate_above_the_error():
    """x2'' = -kappa x2 - c x2' with c = 0.01: g-bar = x2^2 / 2 falls by 10 % over [0, 10],
    which the control points, restarted with the recorded fluctuation, do not see (defects
    5e-4, estimate 3.2e-3, no warning, error 1.7e-2 at tolerance 1e-2). The damping rate
    of the squared amplitude (-c) now grows the defects in the estimate. The default then
    solves the flow-averaged model, which follows the damping: within, unwarned."""
    x1, x2, kappa, c = sp.symbols("x1 x2 kappa c")
    undamped = dn.ODE.second_order({x1: -x1 + x2**2 / 2, x2: -kappa * x2},
                                   x0={x1: 0.0, x2: 1.0}, v0={x1: 0.0, x2: 0.0}, T=10.0,
                                   params={kappa: 1e6})
    x2_dot = undamped.states[3]
    ode = dn.ODE.second_order({x1: -x1 + x2**2 / 2, x2: -kappa * x2 - c * x2_dot},
                              x0={x1: 0.0, x2: 1.0}, v0={x1: 0.0, x2: 0.0}, T=10.0,
                              params={kappa: 1e6, c: 0.01})
    settings = {**SETTINGS, "tolerance": 1e-2, "subgrid_model": "affine"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = dn.solve(ode, **settings)
    assert sol.model.amplitude_rate == pytest.approx(-0.01, rel=1e-6)
    tau = sol.model.average_length
    times = np.linspace(3 * tau, ode.T - tau, 40)
    reference = multiscale.averaged_reference(ode, times, tau, rtol=1e-9)
    error = np.max(np.abs(sol(times) - reference)[[0, 2]])
    assert error > settings["tolerance"]  # the class this test is about
    fired = _model_warnings(caught)
    assert fired and "damped or excited by itself" in str(fired[0].message)
    assert sol.model.estimate.total >= error
    plain = dn.solve(undamped, **settings)
    assert plain.model.amplitude_rate == 0.0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        default = dn.solve(ode, **dict(settings, subgrid_model="auto"))
    assert default.model.subgrid_model == "flow" and not _model_warnings(caught)
    assert np.max(np.abs(default(times) - reference)[[0, 2]]) < settings["tolerance"]


def test_a_resonantly_driven_fast_oscillation_is_warned_with_an_estimate_above_tolerance():
    """A fast rotation (p, q) drives a second one (y, v) at its own frequency, with the slow
    x as amplitude: y's amplitude grows linearly in t, and with it g-bar = y^2 / 10 of x.
    The fast block of J has imaginary eigenvalues (amplitude_rate is 0), and the checks,
    restarted from the recorded fluctuation, see the first amplitude (defects 9e-4,
    estimate 3.8e-3, no warning, error 0.64 at tolerance 1e-2). The drift of g-bar measured
    inside the resolved windows now grows the defects in the estimate."""
    p, q, y, v, x = sp.symbols("p q y v x")
    ode = dn.ODE({p: -1000 * q, q: 1000 * p, y: 1000 * v, v: -1000 * y + x * p,
                  x: -x / 5 + y**2 / 10}, u0=[1.0, 0.0, 1.0, 0.0, 1.0], T=10.0)
    settings = {**SETTINGS, "tolerance": 1e-2}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sol = dn.solve(ode, **settings)
    assert sol.model.inactive == (p, q, y, v) and sol.model.amplitude_rate == 0.0
    tau = sol.model.average_length
    reference = multiscale.averaged_reference(ode, [ode.T - tau], tau, rtol=1e-9)
    error = abs(sol(ode.T - tau)[4] - reference[4, 0])
    assert error > 10 * settings["tolerance"]  # the class this test is about
    fired = _model_warnings(caught)
    assert fired and "beyond what the slow state explains" in str(fired[0].message)
    assert sol.model.estimate.total > settings["tolerance"]
    rate = unfollowed_rate(sol.model)
    assert rate[4] > 0 and not rate[:4].any()


def test_warning_suggests_the_flow_model_where_it_applies():
    """A fast mode driven by a slow forcing (x' = cos t - x y^2, z' = -z + sin(t) y^2, y at
    w = 1000): the affine model is off and warns; the warning suggests subgrid_model='flow'
    (w is a parameter that sets the fast scale) and not 'affine' (the model is affine
    already), and the flow model meets the tolerance against the resolved solution."""
    from scipy.integrate import solve_ivp

    y, v, x, z, w = sp.symbols("y v x z w")
    ode = dn.ODE({y: w * v, v: -w * y, x: sp.cos(dn.t) - x * y**2, z: -z + sp.sin(dn.t) * y**2},
                 u0=[1.0, 0.0, 0.0, 0.0], T=4.0, params={w: 1000.0})
    options = {**SETTINGS, "tolerance": 1e-2}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        affine = dn.solve(ode, subgrid_model="affine", **options)
    message = " ".join(str(m.message) for m in _model_warnings(caught))
    assert affine.model.affine and "subgrid_model='flow'" in message
    assert "subgrid_model='affine'" not in message
    period = 2 * np.pi / 1000
    full = solve_ivp(lambda s, u: [1000 * u[1], -1000 * u[0], np.cos(s) - u[2] * u[0]**2,
                                   -u[3] + np.sin(s) * u[0]**2],
                     (0.0, 4.0 + 2 * period), ode.u0, rtol=1e-10, atol=1e-12, dense_output=True)
    s = np.linspace(4.0 - 2 * period, 4.0 + 2 * period, 2001)
    average = np.trapezoid(full.sol(s), s, axis=1) / (4 * period)
    flow = dn.solve(ode, subgrid_model="flow", **options)
    # measured on [0, 10]: flow 1.2e-5, affine 0.16 (16 x the tolerance)
    assert np.max(np.abs(flow(4.0)[2:] - average[2:])) < 1e-2
    assert np.max(np.abs(affine(4.0)[2:] - average[2:])) > 1e-2
