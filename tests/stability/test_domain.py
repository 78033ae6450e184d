"""Components declared nonnegative (``ODE(..., nonnegative=...)``): a step that takes one below
-atol is rejected and retried shorter, accepted values in [-atol, 0) are set to 0, and a
right-hand side that drives a declared component below zero raises SolverError."""
import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.bench import problems as P

u, v = sp.symbols("u v")

#: (method, tolerance, absolute tolerance): ROBER to 1e11 returned y1 ~ -4e7 (y2 = -4e-6
#: within atol, or the error of the stiff y2 carried by cG(q), drove y1 into the branch
#: y1 = -y3) at each of these, without the declaration (measured before it existed).
LOOSE = [("cG(2)", 1e-2, 1e-6), ("mcG(1)", 1e-2, 1e-2), ("mcG(1)", 1e-2, 1e-6),
         ("mcG(2)", 1e-3, 1e-3), ("mcG(2)", 1e-4, 1e-6), ("mcG(3)", 1e-4, 1e-4),
         ("mdG(1)", 1e-3, 1e-3)]


@pytest.mark.parametrize("method, tol, atol", LOOSE)
def test_rober_declared_nonnegative_is_right_at_loose_tolerances(method, tol, atol, finite):
    p = P.rober(nonnegative=True)
    # the step tolerances at which the failures were measured (calibrated, cG(2) at 1e-2
    # stops: cG(q) does not damp ROBER's y2, see doc/design/tolerance.md)
    sol = dn.solve(p.ode, method=method, tolerance=tol, absolute_tolerance=atol,
                   calibrate_tolerance=False)
    finite(sol)
    assert np.all(np.abs(sol(p.T) - p.final) <= atol + tol * np.abs(p.final))
    assert sol.values.min() >= 0.0  # every nodal value, projected
    assert sol.y.min() >= -atol  # between nodes the polynomials stay within atol


METHODS = ["cG(1)", "cG(2)", "dG(0)", "dG(1)", "mcG(1)", "mcG(2)", "mdG(0)", "mdG(1)"]


@pytest.mark.parametrize("method", METHODS)
def test_a_declaration_that_is_never_active_changes_nothing(method):
    ode = dn.ODE({u: -u, v: u - 2 * v}, u0=[1.0, 0.0], T=3.0)
    declared = dn.ODE({u: -u, v: u - 2 * v}, u0=[1.0, 0.0], T=3.0, nonnegative=True)
    a = dn.solve(ode, method=method, tolerance=1e-6)
    b = dn.solve(declared, method=method, tolerance=1e-6)
    np.testing.assert_array_equal(a.values, b.values)
    np.testing.assert_array_equal(a.k, b.k)


@pytest.mark.parametrize("method", METHODS)
def test_a_right_hand_side_that_leaves_the_domain_raises_where_it_does(method):
    """u' = -1 from u = 1 reaches zero at t = 1: the projected solution would stay at 0
    (u(2) = 0 against the exact -1); it raises there instead, naming u."""
    ode = dn.ODE({u: -1 + 0 * v, v: -v}, u0=[1.0, 1.0], T=2.0, nonnegative=True)
    with pytest.raises(dn.SolverError, match="u, declared nonnegative, leaves") as info:
        dn.solve(ode, method=method, tolerance=1e-6)
    assert abs(info.value.t - 1.0) < 1e-5


@pytest.mark.parametrize("method", ["cG(1)", "dG(0)", "mcG(1)", "mdG(0)"])
def test_fixed_steps_that_leave_the_domain_raise(method):
    ode = dn.ODE({u: -1}, u0=[1.0], T=2.0, nonnegative=[u])
    with pytest.raises(dn.SolverError, match="smaller initial_time_step") as info:
        dn.solve(ode, method=method, fixed_time_step=True, initial_time_step=0.3)
    assert info.value.t == pytest.approx(0.9)


def test_only_the_declared_components_are_constrained():
    ode = dn.ODE({u: -1, v: -1}, u0=[1.0, 1.0], T=2.0, nonnegative=[v])
    with pytest.raises(dn.SolverError, match="v, declared nonnegative"):
        dn.solve(ode, method="dG(1)", tolerance=1e-6)
    free = dn.ODE({u: -1, v: 1}, u0=[1.0, 1.0], T=2.0, nonnegative=[v])
    assert dn.solve(free, method="dG(1)", tolerance=1e-6)(2.0) == pytest.approx([-1.0, 3.0])


@pytest.mark.parametrize("method", ["cG(1)", "mcG(1)"])
def test_a_square_root_of_a_nonnegative_component_stays_defined(method):
    """u' = -sqrt(u), u(0) = 1: u = (1 - t/2)^2 reaches 0 at t = 2 and stays there. Iterates
    dip below 0 near t = 2, where sqrt is nan: declared nonnegative, f reads sqrt(max(u, 0))."""
    ode = dn.ODE({u: -sp.sqrt(u)}, u0=[1.0], T=3.0, nonnegative=[u])
    sol = dn.solve(ode, method=method, tolerance=1e-6)
    assert sol(1.0)[0] == pytest.approx(0.25, abs=1e-6)
    assert sol(3.0)[0] == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(dn.SolverError, match="declare the component nonnegative="):
        dn.solve(dn.ODE({u: -sp.sqrt(u)}, u0=[1.0], T=3.0), method=method, tolerance=1e-6)


@pytest.mark.parametrize("method", ["cG(2)", "mcG(2)"])
def test_a_nonconvergence_message_names_what_is_left_to_try(method):
    """Past the non-Lipschitz point of sqrt(u) Newton's Jacobian is infinite: with Newton
    selected and u declared nonnegative, the message suggests neither of them again, but the
    degree-1 methods that step through it."""
    ode = dn.ODE({u: -sp.sqrt(u)}, u0=[1.0], T=3.0, nonnegative=[u])
    with pytest.raises(dn.SolverError) as info:
        dn.solve(ode, method=method, tolerance=1e-6, nonlinear_solver="newton")
    message = str(info.value)
    assert "Newton's method did not converge" in message
    assert "nonlinear_solver='newton'" not in message and "declare the" not in message
    assert "cG(1) and mcG(1) step through" in message


def test_the_compiled_right_hand_side_reads_a_nonnegative_component_at_zero():
    from dolfinode.compile import lower

    rates = {u: -sp.sqrt(u) + v - u**2, v: -v**3 - u**sp.Rational(3, 2)}
    declared = lower(dn.ODE(rates, u0=[1.0, 1.0], T=1.0, nonnegative=[u]))
    free = lower(dn.ODE(rates, u0=[1.0, 1.0], T=1.0))
    # the non-integer powers read u as 0, the polynomial terms as it is
    np.testing.assert_array_equal(declared.f([-1.0, -2.0], 0.0), [-3.0, 8.0])
    assert np.isnan(free.f([-1.0, -2.0], 0.0)).all()
    np.testing.assert_array_equal(declared.jacobian_matrix([4.0, 1.0], 0.0).toarray(),
                                  free.jacobian_matrix([4.0, 1.0], 0.0).toarray())
