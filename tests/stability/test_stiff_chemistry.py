"""Hard stiff problems of the Test Set: ROBER to t = 1e11, VDPOL (eps = 1e-6), POLLU, and the
conservation laws of ROBER and HIRES.

scipy's BDF returns success on ROBER to 1e11 with atol = 1e-6 and y1 ~ -3e6; dolfinode must
either return a solution within the tolerance of the reference, with no component below -atol,
or raise SolverError."""
import warnings

import numpy as np
import pytest

import dolfinode as dn
from dolfinode.bench import problems as P

#: Every method: the multi-adaptive ones measured in 0.01-0.3 s (mdG(0) raises at t ~ 89
#: after 200,000 steps, in 2 s).
METHODS = ["cG(1)", "cG(2)", "cG(3)", "dG(0)", "dG(1)", "dG(2)", "dG(3)",
           "mcG(1)", "mcG(2)", "mcG(3)", "mdG(0)", "mdG(1)", "mdG(2)", "mdG(3)"]


@pytest.mark.parametrize("method", METHODS)
def test_rober_to_1e11_is_right_or_raises(method, finite):
    p = P.rober()
    tol = atol = 1e-6
    try:
        # maximum_steps bounds the run time; running out of steps must raise, not return
        sol = dn.solve(p.ode, method=method, tolerance=tol, absolute_tolerance=atol,
                       maximum_steps=200_000)
    except dn.SolverError as exc:
        assert exc.t is not None and 0.0 < exc.t < p.T
        return
    finite(sol)
    assert sol.values.min() >= -atol, "a concentration below -atol"
    # within the tolerance of the reference (measured: 2e-3 x tolerance or less; dG(0)
    # raises SolverError at t ~ 9)
    err = np.abs(sol(p.T) - p.final)
    assert np.all(err <= atol + tol * np.abs(p.final)), err
    # conservation: y1 + y2 + y3 = 1 at every sample, to 10 x tolerance
    assert np.max(np.abs(sol.y.sum(axis=0) - 1.0)) <= 10 * tol


def test_rober_to_1e11_returns_a_solution_with_dg1(finite):
    """At least one method gets through (so the test above is not all SolverErrors), and
    it conserves y1 + y2 + y3 = 1 to 10 x tolerance at every sample and every node."""
    p = P.rober()
    tol = 1e-6
    sol = dn.solve(p.ode, method="dG(1)", tolerance=tol, absolute_tolerance=tol,
                   maximum_steps=200_000)
    finite(sol)
    assert P.mescd(sol(p.T), p.final, 1.0) > 6
    assert np.max(np.abs(sol.y.sum(axis=0) - 1.0)) <= 10 * tol
    assert np.max(np.abs(sol.values.sum(axis=-1) - 1.0)) <= 10 * tol


@pytest.mark.parametrize("method, steps", [("dG(2)", 5000), ("dG(3)", 2000)])
def test_rober_to_1e11_takes_few_steps(method, steps, finite):
    """The step grows with t on ROBER's slow decay: measured at tolerance 1e-6 (atol 1e-10)
    dG(2) 1605 steps, dG(3) 594, both with mescd > 11 (the former indicator k^p |R|, which
    grows with k^(p-1) on long time scales, hit 200,000 steps before t = 1e10)."""
    p = P.rober()
    sol = dn.solve(p.ode, method=method, tolerance=1e-6, absolute_tolerance=1e-10,
                   maximum_steps=steps)
    finite(sol)
    assert P.mescd(sol(p.T), p.final, p.atol_ratio) >= 6


@pytest.mark.parametrize("method", ["mcG(1)", "mcG(2)", "mcG(3)", "mdG(1)", "mdG(2)", "mdG(3)"])
def test_rober_to_1e11_multi_adaptive(method, finite):
    """The multi-adaptive error estimate is filtered like the mono-adaptive one,
    (I - gamma k J)^{-1} k R on each sub-slab: on the stiff y2 the unfiltered k |R| stood for
    k |lambda| times its distance from the quasi-steady state, and mcG(2) took 3.9 million
    slabs (25 s; mcG(1) 244,000) with steps growing like t / 10^5. Measured at tolerance 1e-6
    (atol 1e-10): 384-14,262 slabs, mescd 6.4-11.2."""
    p = P.rober()
    tol, atol = 1e-6, 1e-10
    with warnings.catch_warnings():  # (uncalibrated: no ToleranceWarning)
        warnings.simplefilter("error", dn.ToleranceWarning)
        sol = dn.solve(p.ode, method=method, tolerance=tol, absolute_tolerance=atol,
                       maximum_steps=20_000, calibrate_tolerance=False)  # the steps measured
    finite(sol)
    assert P.mescd(sol(p.T), p.final, p.atol_ratio) >= 6
    assert sol.values.min() >= -atol
    assert np.max(np.abs(sol.y.sum(axis=0) - 1.0)) <= 10 * tol


@pytest.mark.parametrize("method", ["mcG(2)", "mcG(3)", "mdG(2)"])
def test_pollu_multi_adaptive_at_tight_tolerance(method, finite):
    """POLLU at tolerance 1e-10 (atol 1e-10): measured 29,904 / 6601 / 25,394 elements and
    mescd 13.9 / 14.4 / 14.7. mcG(2) took 9.3 million elements (83 s) while a step tie along
    y4 -> y3 -> the species with J_ii = -4.4e11 was not passed on (``_propagate``)."""
    p = P.pollu()
    tol = 1e-10
    sol = dn.solve(p.ode, method=method, tolerance=tol, absolute_tolerance=tol,
                   maximum_steps=5000, calibrate_tolerance=False)  # the steps measured
    finite(sol)
    assert sol.stats["elements"] < 100_000
    assert P.mescd(sol(p.T), p.final) >= -np.log10(tol)


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "dG(2)", "dG(3)"])
def test_hires_y7_plus_y8_is_conserved(method, finite):
    tol = 1e-6
    sol = dn.solve(P.hires(), method=method, tolerance=tol)
    finite(sol)
    # 10 x the mixed tolerance atol + rtol |y7 + y8| (atol = tolerance, the default)
    assert np.max(np.abs(sol.y[6] + sol.y[7] - 0.0057)) <= 10 * tol * (1 + 0.0057)


# Measured (tolerance 1e-8, mescd at T; 8 meets the tolerance, and is required): VDPOL cG(2) 11.7,
# dG(2) 14.3, dG(3) 14.0 (the former indicator k^p |R(t_n)|, not scaled by the time scale, gave
# 2.7-4.3).
@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "dG(2)", "dG(3)"])
def test_vdpol_meets_the_tolerance(method, finite):
    p = P.vdpol()
    tol = 1e-8
    sol = dn.solve(p.ode, method=method, tolerance=tol)
    finite(sol)
    assert P.mescd(sol(p.T), p.final) >= -np.log10(tol)   # the tolerance, no slack


@pytest.mark.parametrize("method", ["dG(1)", "dG(2)", "dG(3)", "cG(2)"])
def test_pollu_meets_the_tolerance(method, finite):
    """The error at T within 10 x the tolerance (measured mescd at tolerance 1e-8: 7.2 for
    dG(2), 7.4 for dG(3))."""
    p = P.pollu()
    tol = 1e-8
    sol = dn.solve(p.ode, method=method, tolerance=tol)
    finite(sol)
    assert P.mescd(sol(p.T), p.final) >= -np.log10(tol) - 1
