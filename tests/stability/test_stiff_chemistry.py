"""Hard stiff problems of the Test Set: ROBER to t = 1e11, VDPOL (eps = 1e-6), POLLU, and the
conservation laws of ROBER and HIRES.

scipy's BDF returns success on ROBER to 1e11 with atol = 1e-6 and y1 ~ -3e6; dolfinode must
either return a solution within the tolerance of the reference, with no component below -atol,
or raise SolverError."""
import numpy as np
import pytest

import dolfinode as dn
from dolfinode.bench import problems as P

MONO = ["cG(1)", "cG(2)", "cG(3)", "dG(0)", "dG(1)", "dG(2)", "dG(3)"]


@pytest.mark.parametrize("method", MONO)
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
    err = np.abs(sol(p.T) - p.final)
    assert np.all(err <= 10 * (atol + tol * np.abs(p.final))), err
    # conservation: y1 + y2 + y3 = 1 at every sample, to 10 x tolerance
    assert np.max(np.abs(sol.y.sum(axis=0) - 1.0)) <= 10 * tol


def test_rober_to_1e11_returns_a_solution_with_dg1(finite):
    """At least one method gets through (so the test above is not all SolverErrors)."""
    p = P.rober()
    sol = dn.solve(p.ode, method="dG(1)", tolerance=1e-6, absolute_tolerance=1e-6,
                   maximum_steps=200_000)
    finite(sol)
    assert P.mescd(sol(p.T), p.final, 1.0) > 6


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "dG(2)", "dG(3)"])
def test_hires_y7_plus_y8_is_conserved(method, finite):
    tol = 1e-6
    sol = dn.solve(P.hires(), method=method, tolerance=tol)
    finite(sol)
    # 10 x the mixed tolerance atol + rtol |y7 + y8| (atol = tolerance, the default)
    assert np.max(np.abs(sol.y[6] + sol.y[7] - 0.0057)) <= 10 * tol * (1 + 0.0057)


# Measured (2026-11-22, tolerance 1e-8, mescd at T; 8 would meet the tolerance):
#   VDPOL eps = 1e-6: dG(1) 3.6, dG(2) 2.7, cG(2) 4.3, dG(3) 3.2 (scipy Radau 10.9, BDF 7.1);
#   at tolerance 1e-4 dG(2) reaches 4.2, so the error does not decrease with the tolerance.
# Cause: the step indicator eps = k^p |R(t_n)| / (atol + rtol |U|) of dolfinode/adaptivity.py
# uses the residual at the element's end point, where the collocation-type cG/dG solutions
# nearly satisfy the ODE, and its k^p (p = q or q + 1) is not scaled by the problem's time
# scale: with k ~ 1e-7 in the fast transitions it is far below the true local error.
VDPOL_REASON = ("step-size indicator k^p |R(t_n)| underestimates the error on fast "
                "transitions: measured mescd 2.7-4.3 at tolerance 1e-8")


@pytest.mark.parametrize("method", [
    pytest.param(m, marks=pytest.mark.xfail(strict=True, reason=VDPOL_REASON))
    for m in ["cG(2)", "dG(1)", "dG(2)", "dG(3)"]])
def test_vdpol_meets_the_tolerance(method, finite):
    p = P.vdpol()
    tol = 1e-8
    sol = dn.solve(p.ode, method=method, tolerance=tol)
    finite(sol)
    assert P.mescd(sol(p.T), p.final) >= -np.log10(10 * tol)


@pytest.mark.parametrize("method", ["dG(1)", "dG(2)", "dG(3)", "cG(2)"])
def test_pollu_meets_the_tolerance(method, finite):
    """Measured mescd at tolerance 1e-8: 9.8-10.2 (dG(1..3), cG(2))."""
    p = P.pollu()
    tol = 1e-8
    sol = dn.solve(p.ode, method=method, tolerance=tol)
    finite(sol)
    assert P.mescd(sol(p.T), p.final) >= -np.log10(10 * tol)
