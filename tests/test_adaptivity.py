"""The tolerance means the error at T: calibrated step tolerances (dolfinode.adaptivity)."""
import math
import warnings

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp

import dolfinode as dn
from dolfinode.adaptivity import (
    DELIVERED,
    DELIVERED_MULTI,
    MAX_STEP_TOLERANCE,
    RAMP_GROWTH,
    RAMP_THETA,
    STIFF_RATIO,
    STIFF_TARGET,
    UNDAMPED_DEVIATION,
    UNDAMPED_NEGLIGIBLE,
    accepted_step,
    initial_step,
    next_step,
    predicted_step,
    refined_step,
    step_absolute_tolerance,
    step_tolerance,
    stiff_deviation,
    stiff_factor,
    stiff_loosening,
    undamped_warning,
)
from dolfinode.bench import problems
from dolfinode.bench.multirate import oscillator_bank
from dolfinode.compile import lower
from dolfinode.methods import make_method

PROBLEMS = {"HIRES": problems.hires_problem, "VDPOL": problems.vdpol,
            "harmonic": problems.harmonic_problem}


def scaled_error(problem, method, tolerance, **options):
    """The Test Set's scaled error at T, max |U(T) - u(T)| / (atol_ratio + |u(T)|)."""
    sol = dn.solve(problem.ode, method=method, tolerance=tolerance,
                   absolute_tolerance=problem.atol_ratio * tolerance, **options)
    return np.max(np.abs(sol(problem.T) - problem.final)
                  / (problem.atol_ratio + np.abs(problem.final)))


#: Tolerances per method across its range (first order to 1e-7, as in run_tolerance.py).
SWEEPS = {"cG(1)": (1e-2, 1e-4, 1e-6), "cG(2)": (1e-4, 1e-6, 1e-10), "cG(3)": (1e-3, 1e-6, 1e-9),
          "dG(1)": (1e-2, 1e-4, 1e-6), "dG(2)": (1e-4, 1e-7), "dG(3)": (1e-4, 1e-6, 1e-8)}
#: The sweeps within the band: all but cG(3) and dG(3) on VDPOL, which over-deliver, and
#: but the runs of KNOWN_MISSES.
BAND = [(name, method) for method in SWEEPS for name in PROBLEMS
        if (name, method) not in {("VDPOL", "cG(3)"), ("VDPOL", "dG(3)")}]


@pytest.mark.parametrize("name, method", BAND)
def test_delivered_error_within_ten_times_the_tolerance_and_monotone(name, method):
    """The default: the error at T within [0.1, 10] x tolerance, smaller for a smaller one."""
    problem = PROBLEMS[name]()
    errors = [scaled_error(problem, method, tolerance) for tolerance in SWEEPS[method]]
    for error, tolerance in zip(errors, SWEEPS[method]):
        if (name, method, tolerance) not in KNOWN_MISSES:
            assert 0.1 * tolerance <= error <= 10 * tolerance, (error, tolerance)
    assert np.all(np.diff(errors) < 0)


#: q = 4, 5 (fitted alike; VDPOL, which damps, lands below the band: tolerance.md).
HIGH_SWEEPS = {("HIRES", "cG(4)"): (1e-4, 1e-8), ("harmonic", "cG(5)"): (1e-2, 1e-6, 1e-10),
               ("harmonic", "dG(4)"): (1e-2, 1e-6), ("harmonic", "dG(5)"): (1e-3, 1e-7)}


@pytest.mark.parametrize("name, method", HIGH_SWEEPS)
def test_high_degrees_deliver_within_ten_times_the_tolerance(name, method):
    """cG(4), cG(5), dG(4), dG(5): calibrated too, so not 1e3-1e5 x below the tolerance."""
    problem, tolerances = PROBLEMS[name](), HIGH_SWEEPS[name, method]
    errors = [scaled_error(problem, method, tolerance) for tolerance in tolerances]
    for error, tolerance in zip(errors, tolerances):
        assert 0.1 * tolerance <= error <= 10 * tolerance, (error, tolerance)
    assert np.all(np.diff(errors) < 0)


#: Measured misses (error / tolerance in doc/benchmarks/tolerance.md): VDPOL's stiff
#: components are held to the tolerance (adaptivity.stiff_factor) as HIRES's must be, but
#: VDPOL damps their local errors before T; dG(1) on HIRES at 1e-2 lies 115 x below the
#: oscillator at the same step tolerance, more than the band's width (doc/design/tolerance.md).
KNOWN_MISSES = {("VDPOL", "dG(3)", 1e-6): 0.059, ("HIRES", "dG(1)", 1e-2): 0.053}


@pytest.mark.xfail(strict=True, reason="known misses of the calibration (doc/design/tolerance.md)")
@pytest.mark.parametrize("name, method, tolerance", KNOWN_MISSES)
def test_known_misses(name, method, tolerance):
    """Fails while the miss stands; passes (and so fails strictly) once it is fixed."""
    error = scaled_error(PROBLEMS[name](), method, tolerance)
    assert 0.1 * tolerance <= error <= 10 * tolerance, error / tolerance


#: The multi-adaptive methods' sweeps (their own C: DELIVERED_MULTI).
MULTI_SWEEPS = {"mcG(2)": (1e-3, 1e-6), "mdG(1)": (1e-3, 1e-5)}


@pytest.mark.parametrize("name", ["HIRES", "VDPOL"])
@pytest.mark.parametrize("method", MULTI_SWEEPS)
def test_multi_adaptive_delivered_error_within_ten_times_and_monotone(name, method):
    """mcG(q), mdG(q) by default: the error at T within [0.1, 10] x tolerance, smaller for a
    smaller one."""
    problem = PROBLEMS[name]()
    errors = [scaled_error(problem, method, tolerance) for tolerance in MULTI_SWEEPS[method]]
    for error, tolerance in zip(errors, MULTI_SWEEPS[method]):
        assert 0.1 * tolerance <= error <= 10 * tolerance, (error, tolerance)
    assert errors[1] < errors[0]


#: Multi-adaptive misses of the fitted mapping alone, error / tolerance 16, 42, 17.5 and 11
#: before the step tolerance was bounded by tolerance^((q+1)/(2q+1)) (doc/design/tolerance.md).
LOOSE_MULTI = [("HIRES", "mdG(3)", 1e-6), ("HIRES", "mdG(3)", 1e-7), ("harmonic", "mdG(3)", 1e-2),
               ("harmonic", "mdG(3)", 1e-3)]


@pytest.mark.parametrize("name, method, tolerance", LOOSE_MULTI)
def test_multi_adaptive_step_tolerance_bounded_by_the_resolved_gain(name, method, tolerance):
    """Elements long against their time scale gain less at the node than the fit assumes
    (HIRES: one slab made the whole 42 x): within [0.1, 10] x tolerance with the bound."""
    error = scaled_error(PROBLEMS[name](), method, tolerance)
    assert 0.1 * tolerance <= error <= 10 * tolerance, error / tolerance


@pytest.mark.parametrize("name", ["HIRES", "VDPOL"])
def test_auto_default_tolerance_within_ten_times(name):
    """method="auto" at the default tolerance: the error at T within [0.1, 10] x it."""
    problem = PROBLEMS[name]()
    tolerance = dn.default_parameters["tolerance"]
    error = scaled_error(problem, "auto", tolerance)
    assert 0.1 * tolerance <= error <= 10 * tolerance, error


def test_mono_and_multi_adaptive_deliver_alike():
    """One oscillator 1000x faster than 50 others (auto switches to mcG(2)): at one tolerance
    cG(2), mcG(2) and auto reach errors within 3x of each other, so that auto's choice
    compares runs of equal accuracy (mcG(2) uncalibrated was 27x more accurate than cG(2)
    calibrated)."""
    problem = oscillator_bank(n=50, w=1000.0, T=0.5)
    errors = {m: scaled_error(problem, m, 1e-4) for m in ("cG(2)", "mcG(2)", "auto")}
    assert max(errors.values()) < 3 * min(errors.values()), errors


def test_long_undamped_run_exceeds_the_band_and_the_dual_measures_it():
    """The calibration is of the local error: over ~80 periods of the bank's fast oscillator
    the errors add up to more than 10 x the tolerance (29 x measured), which no step
    tolerance sees; estimate_error's dual does (exact for a linear problem)."""
    problem = oscillator_bank(n=50, w=1000.0, T=0.5)
    sol = dn.solve(problem.ode, method="cG(2)", tolerance=1e-4,
                   absolute_tolerance=problem.atol_ratio * 1e-4)
    error = sol(problem.T) - problem.final
    i = np.argmax(np.abs(error) / (problem.atol_ratio + np.abs(problem.final)))
    assert abs(error[i]) / (problem.atol_ratio + abs(problem.final[i])) > 10 * 1e-4
    estimate = dn.estimate_error(sol, goal=np.eye(problem.ode.N)[i])
    assert estimate.value == pytest.approx(error[i], rel=0.1)


def test_uncalibrated_bounds_each_step_and_over_delivers():
    """calibrate_tolerance=False: the step estimate below the tolerance, the error at T far
    below it for cG(2) (superconvergent nodes)."""
    problem = PROBLEMS["harmonic"]()
    step = scaled_error(problem, "cG(2)", 1e-6, calibrate_tolerance=False)
    assert step < 0.1 * scaled_error(problem, "cG(2)", 1e-6)
    assert step < 1e-7


def test_step_tolerance_is_monotone_bounded_and_identity_where_not_calibrated():
    tolerances = 10.0 ** -np.arange(2, 13)
    for family, q in DELIVERED:
        step = [step_tolerance(make_method(family, q), tol) for tol in tolerances]
        assert np.all(np.diff(step) <= 0) and step[-1] < step[-2]
        assert max(step) <= MAX_STEP_TOLERANCE
        if q > 1:  # superconvergent nodes: the step estimate may be looser than the error
            assert np.all(np.asarray(step) >= tolerances)
    cg1 = make_method("cG", 1)
    assert step_tolerance(cg1, 1e-6) == pytest.approx(1e-6 / DELIVERED["cG", 1][0])
    for family, q in DELIVERED_MULTI:  # every component at its tolerance: aimed tighter
        method = make_method(family, q)
        step = [step_tolerance(method, tol, multi_adaptive=True) for tol in tolerances]
        assert np.all(np.diff(step) <= 0) and max(step) <= MAX_STEP_TOLERANCE
        assert all(s <= step_tolerance(method, tol) for s, tol in zip(step, tolerances))
        # ... and at most what a resolved element's superconvergent node delivers
        assert all(s <= max(tol, tol ** ((q + 1) / (2 * q + 1))) * (1 + 1e-12)
                   for s, tol in zip(step, tolerances))
    for family, q in (("dG", 0), ("cG", 6)):
        assert step_tolerance(make_method(family, q), 1e-6) == 1e-6
    for family, q in (("dG", 0), ("cG", 4), ("dG", 5)):
        assert step_tolerance(make_method(family, q), 1e-6, multi_adaptive=True) == 1e-6


def test_step_absolute_tolerance_never_looser_for_a_tighter_rtol():
    """atol_i is scaled by the calibration's factor at max(atol_i, rtol): rtol's where
    atol_i <= rtol (as before), atol_i's own where larger, which is tighter (the factor
    shrinks as the tolerance grows) and does not move as rtol tightens below atol_i."""
    for multi in (False, True):
        for family, q in DELIVERED_MULTI if multi else DELIVERED:
            method = make_method(family, q)
            atol = np.array([1e-12, 1e-8, 1e-6, 1e-6, 1e-4])
            for rtol in 10.0 ** -np.arange(4, 11):
                step = step_tolerance(method, rtol, multi)
                loop = step_absolute_tolerance(method, atol, rtol, step, multi)
                below = atol <= rtol
                np.testing.assert_allclose(loop[below], atol[below] * step / rtol)
                np.testing.assert_allclose(
                    loop[~below], [step_tolerance(method, a, multi) for a in atol[~below]])
                assert np.all(loop <= atol * step / rtol * (1 + 1e-12))


def chain_end_error(method, rtol, atol, n=200, rate=1000.0):
    """The largest error at the element ends of u_1' = r (1 - u_1), u_i' = r (u_{i-1} -
    u_i), u(0) = 0 on [0, 0.3] (a front along the chain; exact u_i = P(i, r t)), in units
    of atol + rtol max |u_i|, over every 10th stage."""
    from scipy.special import gammainc
    us = sp.symbols(f"c0:{n}")
    rhs = {us[0]: rate * (1 - us[0])}
    rhs.update({us[i]: rate * (us[i - 1] - us[i]) for i in range(1, n)})
    T = 1.5 * n / rate
    sol = dn.solve(dn.ODE(rhs, u0=np.zeros(n), T=T), method, tolerance=rtol,
                   absolute_tolerance=atol)
    worst = 0.0
    for i in range(0, n, 10):
        starts, steps = sol.time_steps(us[i])
        ends = np.minimum(starts + steps, T)
        exact = gammainc(i + 1, rate * ends)
        worst = max(worst, np.max(np.abs(sol(ends)[i] - exact))
                    / (atol + rtol * gammainc(i + 1, rate * T)))
    return worst


@pytest.mark.parametrize("method", ["cG(3)", "dG(2)"])
def test_tighter_rtol_below_atol_does_not_loosen_the_front(method):
    """With atol = 1e-6, rtol 1e-8 scaled atol by rtol's calibration factor, 3.8 x looser
    than at rtol 1e-6: a front along a 200-stage chain took fewer slabs and ended 6.3 x
    (cG(3)) and 9.2 x (dG(2)) the tolerance off at element ends mid-run, against 0.73 x and
    0.87 x at rtol 1e-6 (1000 stages: 19.7 x, 21.5 x), silent: the error at T is far below."""
    loose = chain_end_error(method, 1e-6, 1e-6)
    tight = chain_end_error(method, 1e-8, 1e-6)
    assert tight <= 2 * max(loose, 0.1), (tight, loose)


@pytest.mark.parametrize("method", ["mcG(3)", "mdG(2)", "mdG(3)"])
def test_multi_adaptive_front_within_the_tolerance_at_element_ends(method):
    """Along the front each u_i follows u_{i-1} within its step (r k_i > 1): the two take
    one step (``steps.propagate``'s two-way tie). Where u_i took a longer element over an
    element end of u_{i-1}, or a shorter one inside its element, it ended 4.2 x (mcG(3)),
    7.9 x (mdG(2)) and 10.6 x (mdG(3)) the tolerance off at 1e-6 over every 10th stage
    (13 x, 15 x, 12.7 x over all), the error at T far below; now within 1 x."""
    assert chain_end_error(method, 1e-6, 1e-6) <= 2.0


def test_stiff_components_are_held_to_the_tolerance():
    """stiff_factor takes the calibration's loosening back where the filter reduced a
    component's estimate (no superconvergent nodes there), and only there."""
    loosening = math.log(1e3)
    assert stiff_factor(0.0, 1.0, loosening) == pytest.approx(1e3)
    assert stiff_factor(STIFF_RATIO, 1.0, loosening) == 1.0
    assert stiff_factor(1.0, 1.0, loosening) == stiff_factor(1.0, 0.0, loosening) == 1.0
    assert 1.0 < stiff_factor(0.5 * STIFF_RATIO, 1.0, loosening) < 1e3
    cg3 = make_method("cG", 3)
    assert stiff_loosening(cg3, 1e-6, step_tolerance(cg3, 1e-6)) == pytest.approx(
        math.log(step_tolerance(cg3, 1e-6) / (STIFF_TARGET["cG", 3] * 1e-6)))
    assert stiff_loosening(make_method("cG", 1), 1e-6, 1e-7) == 0.0


def stiff_read_problem(name):
    """(ode, f for scipy) of a stiff component read by others: "pair", a' = -1000 (a - cos t)
    with b' = a; "mix", a' = -1e4 (a - b^2) slaved to the rotation (b, c), read by
    d' = a - d."""
    a, b, c, d = sp.symbols("a b c d")
    if name == "pair":
        return (dn.ODE({a: -1000 * (a - sp.cos(dn.t)), b: a}, u0=[0.0, 0.0], T=3.0),
                lambda t, u: [-1000 * (u[0] - np.cos(t)), u[0]])
    return (dn.ODE({a: -1e4 * (a - b**2), b: c, c: -b, d: a - d}, u0=[0.0, 1.0, 0.0, 0.0],
                   T=5.0),
            lambda t, u: [-1e4 * (u[0] - u[1]**2), u[2], -u[1], u[0] - u[3]])


#: Runs silent above 10 x at element ends before the multi-adaptive loop held stiff
#: components (largest error at an element end / (atol + rtol max |u_i|)): the pair's b
#: inside a's long elements (mdG(2) 225 x, mdG(3) 112 x, mcG(3) 74 x), the mix's a (mdG(1)
#: 94 x, mcG(2) 12 x); qa-probes/s16/STIFFM16.
STIFF_READ = [("pair", "mdG(2)", 1e-8), ("pair", "mdG(3)", 1e-7), ("pair", "mcG(3)", 1e-7),
              ("mix", "mdG(1)", 1e-8), ("mix", "mcG(2)", 1e-7)]


@pytest.mark.parametrize("name, method, tolerance", STIFF_READ)
def test_multi_adaptive_stiff_component_within_ten_times_at_every_element_end(name, method,
                                                                               tolerance):
    """A stiff component's elements are held to the tolerance in the multi-adaptive loop too
    (adaptivity.stiff_factor, STIFF_TARGET_MULTI): every component's error at every element
    end is within 10 x (atol + rtol max |u_i|), or the run warns. Without it the error at T
    was within 10 x and estimated right (pair, mdG(2) at 1e-8: 3.0 x, estimated 2.1 x): the
    errors mid-run are a's, damped before T, or b's inside a's element, which cancel at its
    end, so no estimate of the error at T sees them."""
    ode, f = stiff_read_problem(name)
    reference = solve_ivp(f, (0.0, ode.T), np.array(ode.u0, float), method="Radau",
                          rtol=1e-13, atol=1e-15, dense_output=True)
    size = np.max(np.abs(reference.sol(np.linspace(0.0, ode.T, 4001))), axis=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", dn.ToleranceWarning)
        sol = dn.solve(ode, method, tolerance=tolerance)
    warned = [w for w in caught if issubclass(w.category, dn.ToleranceWarning)]
    worst = 0.0
    for i in range(ode.N):
        starts, steps = sol.time_steps(i)
        ends = starts + steps
        error = np.abs(sol(ends)[i] - reference.sol(ends)[i]) / (tolerance * (1 + size[i]))
        worst = max(worst, np.max(error))
    assert worst <= 10 or warned, worst


@pytest.mark.parametrize("method", ["mdG(2)", "mdG(3)"])
def test_error_mid_run_at_element_ends_is_estimated_and_warned(method):
    """mdG(2) on the mix at 1e-8: d reads a inside a's long elements, whose Galerkin
    polynomial is far off there (right at a's own ends), and is 20 x the tolerance off at
    its element ends mid-run, 0.06 x at T, where the estimate looks; its recursion passes
    every element end, and "global error mid-run" is the largest error at the ends that read
    another component inside its element (scaled as the tolerance means it), with a
    ToleranceWarning above 10 x. mdG(3) stays within, unwarned."""
    ode, f = stiff_read_problem("mix")
    tolerance = 1e-8
    reference = solve_ivp(f, (0.0, ode.T), np.array(ode.u0, float), method="Radau",
                          rtol=1e-13, atol=1e-15, dense_output=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", dn.ToleranceWarning)
        sol = dn.solve(ode, method, tolerance=tolerance)
    warned = [str(w.message) for w in caught if issubclass(w.category, dn.ToleranceWarning)]
    worst = 0.0
    for i in range(ode.N):
        starts, steps = sol.time_steps(i)
        ends = starts + steps
        exact = reference.sol(ends)[i]
        worst = max(worst, np.max(np.abs(sol(ends)[i] - exact) / (1 + np.abs(exact))))
    peak = sol.stats["global error mid-run"]
    assert 0 < peak <= 1.2 * worst
    if worst > 10 * tolerance:
        assert peak == pytest.approx(worst, rel=0.2)
        assert any("mid-run" in w and "in d" in w for w in warned), warned
    else:
        assert not warned, warned


@pytest.mark.parametrize("method", ["mcG(3)", "mdG(2)"])
@pytest.mark.parametrize("choice", ["auto", True])
def test_error_mid_run_along_a_chain_front_is_estimated_at_every_element_end(method, choice):
    """A front along a 100-stage chain at 1e-6: mdG(2) ends 16 x the tolerance off at
    element ends mid-run, mcG(3) 3.6 x, both far below at T. "global error mid-run" is the
    largest error at every element end of every component, on both estimates (the stage
    systems, True; the slab estimate, "auto" for this size), scaled as the tolerance means
    it, and warned above 10 x. Before, the slab estimate kept none, and the stage systems
    only the ends that read another component inside its element (mcG(3) on 200 stages:
    7.85 x of 12.9 x, silent)."""
    from scipy.special import gammainc
    n, rate, tolerance = 100, 1000.0, 1e-6
    us = sp.symbols(f"c0:{n}")
    rhs = {us[0]: rate * (1 - us[0])}
    rhs.update({us[i]: rate * (us[i - 1] - us[i]) for i in range(1, n)})
    T = 1.5 * n / rate
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", dn.ToleranceWarning)
        sol = dn.solve(dn.ODE(rhs, u0=np.zeros(n), T=T), method, tolerance=tolerance,
                       estimate_global_error=choice)
    warned = [str(w.message) for w in caught if issubclass(w.category, dn.ToleranceWarning)]
    worst = 0.0
    for i in range(n):
        starts, steps = sol.time_steps(us[i])
        ends = np.minimum(starts + steps, T)
        exact = gammainc(i + 1, rate * ends)
        worst = max(worst, np.max(np.abs(sol(ends)[i] - exact) / (1 + exact)))
    assert sol.stats["global error mid-run"] == pytest.approx(worst, rel=0.01)
    assert sol.stats["global error estimate"] < tolerance
    assert bool(warned) == (worst > 10 * tolerance), warned
    assert all("mid-run" in w for w in warned), warned


def test_error_mid_run_of_a_linear_system_estimated_mode_by_mode():
    """The harmonic oscillator's stage recursion goes mode by mode (a constant J): its
    "global error mid-run" is the largest error at the element ends too (mcG(2) at 1e-4:
    8.7 x, 5.3 x at T; before, none was kept there)."""
    problem = problems.harmonic_problem()
    tolerance = 1e-4
    atol = problem.atol_ratio * tolerance
    sol = dn.solve(problem.ode, "mcG(2)", tolerance=tolerance, absolute_tolerance=atol)
    worst = 0.0
    for i in range(problem.ode.N):
        starts, steps = sol.time_steps(i)
        ends = np.minimum(starts + steps, problem.ode.T)
        exact = problem.exact(ends)[i]
        worst = max(worst, np.max(np.abs(sol(ends)[i] - exact) / (atol / tolerance
                                                                   + np.abs(exact))))
    assert sol.stats["global error mid-run"] == pytest.approx(worst, rel=0.01)


def test_rober_cg_says_it_cannot_damp_and_dg_steps_over():
    """cG(q) is not L-stable: on ROBER at 1e-3 it took 322,000 slabs; now it stops after a
    few thousand with a SolverError that names dG(q), which reaches T in a few hundred
    slabs within 10 x the tolerance."""
    problem = problems.rober()
    options = {"tolerance": 1e-3, "absolute_tolerance": problem.atol_ratio * 1e-3}
    with pytest.raises(dn.SolverError, match=r"not L-stable.*method='dG\(2\)'") as failure:
        dn.solve(problem.ode, method="cG(2)", **options)
    assert failure.value.t < problem.T
    sol = dn.solve(problem.ode, method="dG(2)", **options)
    assert sol.stats["time slabs"] < 300
    error = np.max(np.abs(sol(problem.T) - problem.final)
                   / (problem.atol_ratio + np.abs(problem.final)))
    assert error <= 10 * 1e-3


def test_refined_first_step_is_hnw_within_k0_and_100_k0():
    u0, atol, rtol, order = np.array([1.0, 2.0]), np.full(2, 1e-6), 1e-3, 4.0
    w = 1 / (atol + rtol * np.abs(u0))
    f0 = -u0  # u' = -u: f1 - f0 = k0 u0, so d2 = |u0| w = d1
    k0 = initial_step(f0, u0, atol, rtol, 10.0)
    f1 = -(u0 + k0 * f0)
    d = max(np.max(np.abs(f0) * w), np.max(np.abs(f1 - f0) * w) / k0)
    assert refined_step(k0, f0, f1, u0, atol, rtol, order, 10.0) == pytest.approx(
        min(100 * k0, max(k0, (0.01 / d) ** (1 / order))), rel=1e-12)
    assert refined_step(k0, f0, f1, u0, atol, rtol, 1.0, 10.0) == k0  # HNW's k1 below k0: k0
    assert refined_step(k0, 0 * f0, 0 * f1, u0, atol, rtol, order, 10.0) == k0
    assert refined_step(k0, f0, np.array([np.nan, 1.0]), u0, atol, rtol, order, 10.0) == k0
    assert refined_step(1e-12, f0, f0, u0, atol, rtol, order, 10.0) == pytest.approx(1e-10)
    # an initial layer: |f0| / |f1 - f0| x k0 = 1 / 1000 below INITIAL_LAYER x span
    assert refined_step(k0, f0, f0 + 1000 * (f1 - f0), u0, atol, rtol, order, 1e4) == k0


def test_predicted_step_follows_an_error_constant_changing_geometrically():
    """On eps_n = C_n k_n^P with C_(n+1) / C_n constant (a step that must keep shrinking),
    Gustafsson's step from two accepted steps gives eps = safety^P exactly."""
    order, safety, growth = 4.0, 0.9, 2.0

    def eps(n, k):
        return 1e6 * growth**n * k**order

    k_prev, k = 0.03, 0.025
    for n in range(1, 6):
        k_new = predicted_step(k, eps(n, k), k_prev, eps(n - 1, k_prev), order, safety)
        assert eps(n + 1, k_new) == pytest.approx(safety**order, rel=1e-12)
        k_prev, k = k, k_new


def test_accepted_step_follows_a_shrinking_step_without_rejections():
    """The model above from an accepted step: the PI step alone (next_step) lags and every
    other step is rejected (VDPOL with dG(3) at 1e-6 approaching its fast transitions: 56
    of its 62 rejections); the mono-adaptive dG(q) rule (accepted_step) rejects none. On
    growing steps it is the PI step."""
    order, safety, growth = 4.0, 0.9, 2.0

    def rejections(rule):
        n, k, k_prev, eps_prev, count = 0, 0.02, 0.0, 0.5, 0
        while n < 40:
            eps = 1e6 * growth**n * k**order
            if eps > 1.0:
                count, k = count + 1, next_step(k, eps, 1.0, order, safety, False)
                continue
            n, k_prev, eps_prev, k = n + 1, k, eps, rule(k, eps, k_prev, eps_prev)
        return count

    assert rejections(lambda k, eps, k_prev, eps_prev:
                      next_step(k, eps, eps_prev, order, safety, True)) >= 15
    assert rejections(lambda k, eps, k_prev, eps_prev:
                      accepted_step(k, eps, k_prev, eps_prev, order, safety, 1.0)) == 0
    for k_prev in (0.0, 0.5):  # none before, or a shorter one
        assert accepted_step(1.0, 0.3, k_prev, 0.01, order, safety, 1.0) == next_step(
            1.0, 0.3, 0.01, order, safety, True)


def test_vdpol_rejects_few_slabs():
    """VDPOL with dG(3) at 1e-6 approaches its fast transitions without alternating
    accepted and rejected slabs (62 rejected besides 256 accepted with the PI step alone),
    at the same accuracy (7.6 digits)."""
    problem = problems.vdpol()
    options = {"method": "dG(3)", "tolerance": 1e-6,
               "absolute_tolerance": problem.atol_ratio * 1e-6}
    sol = dn.solve(problem.ode, **options)
    assert sol.stats["rejected steps"] <= 15
    assert problems.mescd(sol(problem.T), problem.final, problem.atol_ratio) > 7.0
    for _ in range(2):  # the third call takes the prepared path: the controller starts afresh
        again = dn.solve(problem.ode, **options)
    np.testing.assert_array_equal(again.time_steps()[1], sol.time_steps()[1])


@pytest.mark.parametrize("problem", [problems.hires_problem(), problems.brusselator(20)],
                         ids=["HIRES", "bruss-20"])
def test_dg_first_step_is_accepted_and_shortens_the_ramp(problem):
    """The refined first step of dG(3) is accepted as it is (its estimate within the
    acceptance band), is at least the HNW guess k0, and the run from it takes fewer slabs
    than the run from k0 at a loose tolerance."""
    ode, tol = problem.ode, 1e-2
    atol = problem.atol_ratio * tol
    sol = dn.solve(ode, method="dG(3)", tolerance=tol, absolute_tolerance=atol)
    f0 = np.array(lower(ode).f(ode.u0, ode.t0))
    k0 = initial_step(f0, ode.u0, np.full(ode.N, atol), tol, ode.T - ode.t0)
    _, k = sol.time_steps()
    assert k[0] > 5 * k0
    assert sol.stats["rejected steps"] == 0
    from_k0 = dn.solve(ode, method="dG(3)", tolerance=tol, absolute_tolerance=atol,
                       initial_time_step=k0)
    assert len(k) < from_k0.stats["time slabs"]
def solve_warned(problem, method, tolerance):
    """(scaled error at T, the ToleranceWarnings) of a default solve."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", dn.ToleranceWarning)
        error = scaled_error(problem, method, tolerance)
    return error, [w for w in caught if issubclass(w.category, dn.ToleranceWarning)]


def test_out_of_sample_miss_is_not_silent():
    """ROBER, not used in fitting: cG(2) at 1e-7 carries y2's deviation from its
    quasi-steady state undamped while y2 decays below it, and y1 drifts (26 x measured).
    The run is within the band, or it says so, naming y2 and dG(2)."""
    error, warned = solve_warned(problems.rober(), "cG(2)", 1e-7)
    assert error <= 10 * 1e-7 or warned, error / 1e-7
    if warned:
        assert "y2" in str(warned[0].message) and "dG(2)" in str(warned[0].message)


@pytest.mark.parametrize("tolerance", [1e-6, 1e-8, 1e-9])
def test_multi_adaptive_out_of_sample_miss_is_not_silent(tolerance):
    """mcG(2) on ROBER carries y2's deviation undamped as cG(2) does (70 x, 45 x and 14 x
    measured, no warning before the multi-adaptive loop recorded it; at 1e-9 the deviation
    at T is 0.075 x y2): the run is within the band or says so; the undamped deviation's
    warning names y2 and mdG(2). (With stiff components held to the tolerance, at 1e-6 y2's
    deviation at T stays below its threshold and the global estimate warns: 97.5 x
    estimated, 60 x measured.)"""
    error, warned = solve_warned(problems.rober(), "mcG(2)", tolerance)
    assert error <= 10 * tolerance or warned, error / tolerance
    for caught in warned:
        if "not L-stable" in str(caught.message):
            assert "y2" in str(caught.message) and "mdG(2)" in str(caught.message)


@pytest.mark.parametrize("name, method, tolerance", [
    ("HIRES", "mcG(2)", 1e-4), ("POLLU", "mcG(2)", 1e-5), ("ROBER", "mcG(3)", 1e-6)])
def test_multi_adaptive_no_false_alarm(name, method, tolerance):
    """Multi-adaptive runs within the band raise no ToleranceWarning."""
    problem = {"HIRES": problems.hires_problem, "POLLU": problems.pollu,
               "ROBER": problems.rober}[name]()
    error, warned = solve_warned(problem, method, tolerance)
    assert error <= 10 * tolerance and not warned, (error / tolerance, warned)


@pytest.mark.parametrize("name, method, tolerance", [
    ("POLLU", "cG(2)", 1e-5), ("POLLU", "dG(2)", 1e-7), ("VDPOLM", "cG(2)", 1e-7),
    ("HIRES", "cG(2)", 1e-4)])
def test_out_of_sample_within_the_band_without_warning(name, method, tolerance):
    """Problems the mapping was not fitted on (and HIRES's run closest to a warning: a
    deviation of 0.22 that is not growing into T): within [0.1, 10] x, no false alarm
    (VDPOLM's cG(2) warns of its transition's phase mid-run, 5e5 x off there, measured)."""
    problem = {"POLLU": problems.pollu, "VDPOLM": problems.vdpolm,
               "HIRES": problems.hires_problem}[name]()
    error, warned = solve_warned(problem, method, tolerance)
    assert 0.1 * tolerance <= error <= 10 * tolerance, error / tolerance
    warned = [w for w in warned if "error mid-run" not in str(w.message)]
    assert not warned, str(warned[0].message)


def test_undamped_warning_only_for_even_cg_growing_into_t():
    """cG(q) keeps a stiff deviation for q even (R(-inf) = +1); q odd alternates it and dG
    damps it; a deviation not still growing at T, one negligible against the tolerance and
    one of a component that drives no other are not warned about."""
    big, size = 2 * UNDAMPED_DEVIATION, 10 * UNDAMPED_NEGLIGIBLE
    cg2 = make_method("cG", 2)
    assert "dG(2)" in undamped_warning(cg2, big, big, size, True, "y2")
    assert undamped_warning(make_method("cG", 3), big, big, size, True, "y2") is None
    assert undamped_warning(make_method("dG", 2), big, big, size, True, "y2") is None
    small = 0.5 * UNDAMPED_DEVIATION
    assert undamped_warning(cg2, small, small, size, True, "y2") is None
    assert undamped_warning(cg2, 10 * big, big, size, True, "y2") is None
    assert undamped_warning(cg2, big, big, 0.1 * UNDAMPED_NEGLIGIBLE, True, "y2") is None
    assert undamped_warning(cg2, big, big, size, False, "y2") is None
    assert stiff_deviation(1e-3, 1.0, 1e-2) == pytest.approx(0.1)
    assert stiff_deviation(STIFF_RATIO, 1.0, 1e-2) == 0.0  # not reduced by the filter
    assert stiff_deviation(1e-3, 1.0, 0.0) == 0.0


@pytest.mark.parametrize("declare", [
    lambda: problems.stiff_decay(lam=1000.0, T=10.0)[0],  # drives nothing: 0.001 x
    lambda: problems.rober().ode])  # atol = rtol: y2's deviation 1e-8 x its tolerance
def test_no_warning_where_the_deviation_cannot_matter(declare):
    """Runs whose last stiff deviation is large relative to its component (3.5 x, 1.7 x)
    but harmless."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", dn.ToleranceWarning)
        dn.solve(declare(), method="cG(2)", tolerance=1e-4)


def test_prepared_solver_warns_as_solve_does():
    problem = problems.rober()
    solver = dn.Solver(problem.ode, method="cG(2)", tolerance=1e-7,
                       absolute_tolerance=problem.atol_ratio * 1e-7)
    with pytest.warns(dn.ToleranceWarning, match="y2"):
        solver.solve()
    with warnings.catch_warnings():
        warnings.simplefilter("error", dn.ToleranceWarning)
        dn.Solver(problem.ode, method="cG(2)", tolerance=1e-9,
                  absolute_tolerance=problem.atol_ratio * 1e-9).solve()  # 1.6 x, no warning


def test_accepted_step_follows_a_growing_ramp():
    """On eps_n = C_n k_n^P with C_n shrinking geometrically (steps that must grow by g a
    slab, k ~ t: ROBER), the PI step settles where safety eps^(-0.3/P) = g; accepted_step,
    where Newton contracts fast and g >= RAMP_GROWTH, settles at the estimate of a constant
    step, safety^(P/0.3), with the same growth; on a slower ramp, or where Newton contracts
    slowly, it is the PI step."""
    order, safety = 4.0, 0.9

    def settled(growth, theta):
        k_prev, k, eps_prev = 0.0, 1e-6, 0.5
        for n in range(300):
            eps = growth ** (-order * n) * 1e20 * k**order
            k_prev, k, eps_prev = k, accepted_step(k, eps, k_prev, eps_prev, order, safety,
                                                   theta), eps
        return eps, k / k_prev

    for growth, theta in ((1.5, 2 * RAMP_THETA), (1.2, RAMP_THETA)):
        eps, ratio = settled(growth, theta)
        assert eps == pytest.approx((safety / growth) ** (order / 0.3), rel=1e-6)
        assert ratio == pytest.approx(growth, rel=1e-9)
    assert RAMP_GROWTH > 1.2
    eps, ratio = settled(1.5, RAMP_THETA)
    assert eps == pytest.approx(safety ** (order / 0.3), rel=1e-6)
    assert ratio == pytest.approx(1.5, rel=1e-9)


def test_rober_steps_follow_its_ramp():
    """ROBER with dG(3) at 1e-5: its steps grow with t over 20 decades, Newton contracting
    at about 0.01; following the ramp it takes fewer than 110 slabs (125 with the PI step
    alone) for at least the digits the PI step gave (6.85)."""
    problem = problems.rober()
    sol = dn.solve(problem.ode, method="dG(3)", tolerance=1e-5,
                   absolute_tolerance=problem.atol_ratio * 1e-5)
    assert sol.stats["time slabs"] < 110
    assert sol.stats["rejected steps"] == 0
    assert problems.mescd(sol(problem.T), problem.final, problem.atol_ratio) > 6.85
