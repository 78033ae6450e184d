"""A solve that cannot continue raises SolverError naming the time reached, quickly."""
import math
import time

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn

u = sp.Symbol("u")


@pytest.mark.parametrize("method", ["cG(1)", "cG(2)", "dG(1)", "dG(2)"])
def test_finite_time_blowup(method):
    start = time.perf_counter()
    with pytest.raises(dn.SolverError) as info:
        dn.solve(dn.ODE({u: u**2}, u0=[1.0], T=2.0), method=method, tolerance=1e-6)
    assert abs(info.value.t - 1.0) < 1e-3
    assert "t = " in str(info.value)
    assert time.perf_counter() - start < 30


def test_fixed_step_through_singularity_reports_time():
    with pytest.raises(dn.SolverError, match="initial_time_step") as info:
        dn.solve(dn.ODE({u: u**2}, u0=[1.0], T=2.0), method="cG(1)", fixed_time_step=True,
                 initial_time_step=0.1)
    assert 0.5 < info.value.t <= 1.0


def test_maximum_steps():
    with pytest.raises(dn.SolverError, match="maximum_steps") as info:
        dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0), method="dG(0)", tolerance=1e-12,
                 maximum_steps=100)
    assert "blow up" not in str(info.value)


def test_maximum_steps_with_fixed_steps_names_the_step_count_not_the_tolerance():
    # it advised a looser tolerance, a higher order, or (1e7 steps of 1e-7) automatic
    # modeling for a fast oscillation, none of which sets a fixed step
    with pytest.raises(dn.SolverError, match=r"maximum_steps was reached at t = 0\.99 .* with "
                       r"fixed_time_step: the step 0\.01 takes 100 steps over \[t0, T\], 99 "
                       r"taken .* raise maximum_steps or give a longer initial_time_step$"):
        dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0), method="cG(1)", fixed_time_step=True,
                 initial_time_step=0.01, maximum_steps=99)


def test_maximum_steps_near_a_blowup_says_so():
    # dG(0) creeps towards the singularity of u' = u^2 at t = 1 until maximum_steps (it gave
    # only "raise maximum_steps, loosen the tolerance, ...")
    with pytest.raises(dn.SolverError, match=r"maximum_steps was reached at t = 0\.99.*the steps "
                       r"shrank to .* while max \|u\| grew .*-fold since t0: the solution may "
                       r"blow up near this time; raise maximum_steps"):
        dn.solve(dn.ODE({u: u**2}, u0=[1.0], T=2.0), method="dG(0)", tolerance=1e-3,
                 maximum_steps=20000)


@pytest.mark.parametrize("method", ["mcG(1)", "mdG(0)"])
def test_maximum_steps_multi_adaptive(method):
    # the multi-adaptive loop ignored maximum_steps: mcG(1) returned 1078 slabs for 2
    with pytest.raises(dn.SolverError, match="maximum_steps was reached"):
        dn.solve(dn.ODE({u: -u}, u0=[1.0], T=1.0), method=method, tolerance=1e-8,
                 maximum_steps=2)


def test_nonfinite_initial_rhs():
    with pytest.raises(ValueError, match="not finite"):
        dn.solve(dn.ODE({u: 1 / u}, u0=[0.0], T=1.0))


def test_no_nan_in_returned_solution():
    sol = dn.solve(dn.ODE({u: -u**3}, u0=[10.0], T=5.0), method="dG(1)", tolerance=1e-6)
    assert np.all(np.isfinite(sol.values)) and np.all(np.isfinite(sol.y))


def test_solver_error_is_runtime_error():
    assert issubclass(dn.SolverError, RuntimeError)


@pytest.mark.parametrize("solver, suggested", [("fixed-point", True), ("newton", False)])
def test_a_fixed_step_nonconvergence_suggests_newton_unless_it_was_used(solver, suggested):
    """u' = -1e4 (u - cos t) with steps of 0.1: fixed point cannot converge (k lambda = 1000);
    Newton converges for this linear f, so it fails on u' = -sqrt(|u|) (infinite Jacobian at
    0) instead."""
    rhs = -1e4 * (u - sp.cos(dn.t)) if solver == "fixed-point" else -sp.sqrt(sp.Abs(u - 0.5))
    ode = dn.ODE({u: rhs}, u0=[1.0], T=2.0)
    with pytest.raises(dn.SolverError, match="did not converge") as info:
        dn.solve(ode, method="cG(2)", fixed_time_step=True, initial_time_step=0.1,
                 nonlinear_solver=solver)
    assert ("nonlinear_solver='newton'" in str(info.value)) == suggested


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)"])
def test_growth_to_overflow_is_called_a_blowup_without_advising_the_method_used(method):
    """u' = 1000 u overflows near t = 0.71: Newton stopped converging there and the message
    said to try a dG(q) method (to dG(1) too) or to look for a singularity, though max |u|
    had grown 1e305-fold."""
    with pytest.raises(dn.SolverError, match="may blow up") as info:
        dn.solve(dn.ODE({u: 1000 * u}, u0=[1.0], T=1.0), method=method, tolerance=1e-6)
    assert "dG(q)" not in str(info.value)
    assert abs(info.value.t - 0.709) < 0.01


def test_a_decay_faster_than_double_precision_resolves_is_not_sent_to_dg():
    """u' = -1e20 u on [0, 1] needs steps below the 1e-20 that double precision resolves at
    t = 0: dG(1) with Newton was told to use a dG(q) method with Newton."""
    ode = dn.ODE({u: -1e20 * u}, u0=[1.0], T=1.0)
    with pytest.raises(dn.SolverError, match="faster than double precision") as info:
        dn.solve(ode, method="dG(1)", tolerance=1e-6, nonlinear_solver="newton")
    assert "use a dG(q)" not in str(info.value)


def test_an_interval_too_short_for_double_precision_at_its_times_raises():
    # (t0 = 1e15, T = 1e15 + 1 raised SolverError "tolerance too tight" from the loop)
    ode = dn.ODE({u: -u}, u0=[1.0], t0=1e15, T=1e15 + 1)
    with pytest.raises(ValueError, match=r"shorter than the smallest step double precision "
                       r"resolves there .* t0 = 0 and T = 1$"):
        dn.solve(ode)


@pytest.mark.parametrize("method", ["cG(2)", "dG(1)", "mdG(1)"])
@pytest.mark.parametrize("rhs, exact", [(1 - u, 1 - math.exp(-5.0)),
                                        (sp.Heaviside(dn.t - 1e9 - 1.5), 3.5)])
def test_first_step_far_from_t0_zero_is_resolvable(method, rhs, exact):
    # from u = 0 the first guess 1e-6 (T - t0) = 5e-6, at t0 or after the jump, was below the
    # 1e-5 that double precision resolves at t = 1e9: "the time step fell to 5e-06 at t = 1e9"
    ode = dn.ODE({u: rhs}, u0=[0.0], t0=1e9, T=1e9 + 5)
    sol = dn.solve(ode, method=method, tolerance=1e-6)
    assert abs(sol(1e9 + 5)[0] - exact) <= 1e-5


def test_maximum_steps_from_zero_gives_no_ratio_to_zero():
    # u' = 1 + u^2 from u0 = 0 (tan t, singular at pi / 2): "grew 3.28e+306-fold" before
    with pytest.raises(dn.SolverError, match=r"grew from 0 at t0 to .*blow up") as info:
        dn.solve(dn.ODE({u: 1 + u**2}, u0=[0.0], T=2.0), method="dG(0)", tolerance=1e-3,
                 maximum_steps=20000)
    assert "fold" not in str(info.value)


def test_unresolved_fast_oscillation_is_not_called_a_blowup():
    x1, x2, kappa = sp.symbols("x1 x2 kappa")
    ode = dn.ODE.second_order({x1: -x1 + x2**2 / 2, x2: -kappa * x2}, x0={x1: 0.0, x2: 1.0},
                              v0={x1: 0.0, x2: 0.0}, T=100.0, params={kappa: 1e12})
    with pytest.raises(dn.SolverError, match="maximum_steps") as info:
        dn.solve(ode, method="cG(1)", tolerance=1e-3, maximum_steps=2000)
    message = str(info.value)
    assert "blow up" not in message and "fold" not in message
    assert "automatic_modeling=True" in message and "nonlinear_solver='newton'" in message


@pytest.mark.parametrize("method", ["dG(1)", "cG(1)", "mcG(1)"])
def test_a_right_hand_side_undefined_past_a_time_is_blamed_on_t(method):
    """Issue 32: sqrt(2 - t) under dG(1) was reported as a Newton failure suggesting a dG(q)
    method and a nonnegative component."""
    y = sp.Symbol("y")
    with pytest.raises(dn.SolverError) as info:
        dn.solve(dn.ODE({y: sp.sqrt(2 - dn.t)}, u0=[0.0], T=3.0), method)
    message = str(info.value)
    assert message.startswith("f is not defined past t = 2: a non-integer power in the "
                              "right-hand side of y gets 2 - t = -")
    assert "depends on t alone" in message and "smaller T" in message
    assert "dG(q)" not in message and "nonnegative" not in message


def test_a_right_hand_side_undefined_for_a_state_names_the_component():
    y, z = sp.symbols("y z")
    with pytest.raises(dn.SolverError) as info:
        dn.solve(dn.ODE({y: 1, z: sp.log(1.5 - y)}, u0=[0.0, 0.0], T=3.0), "cG(1)")
    message = str(info.value)
    assert "log in the right-hand side of z gets 1.5 - y = -" in message
    assert "from the values of y" in message


def test_a_tolerance_below_double_precision_at_the_solution_size_is_refused():
    """Issue 32: tolerance = absolute_tolerance = 1e-20 ground through 10^7 cG(2) slabs."""
    y, z = sp.symbols("y z")
    ode = dn.ODE({y: -y, z: -z}, u0=[1.0, 1e-30], T=1.0)
    with pytest.raises(ValueError, match="tolerance of y .* is below what double precision "
                                         "resolves at that size"):
        dn.solve(ode, "cG(2)", tolerance=1e-20, absolute_tolerance=1e-20)
    # a tiny absolute tolerance for tiny values is resolvable: allowed
    sol = dn.solve(ode, "cG(2)", tolerance=1e-6, absolute_tolerance={y: 1e-8, z: 1e-36})
    assert sol(1.0)[1] == pytest.approx(1e-30 * np.exp(-1.0), rel=1e-5)


def test_a_step_underflow_without_growth_is_not_called_a_blowup():
    """Issue 30: a stiff multi-adaptive run whose steps fell to the rounding floor at
    t = 8.3e9 was told the solution may blow up; max |u| had not grown."""
    from dolfinode import timeslab as ts
    from dolfinode.failures import failure_message

    ode = dn.ODE({u: -u}, u0=[1.0], T=1e13)
    bounded = failure_message(ts.UNDERFLOW, (8.3e9, 8e-5), False, np.array([0.5]), None,
                              None, True, ode, 1000)
    assert "not a blow-up" in bounded and "dG(q)" in bounded and "blow up" not in bounded
    assert "singular" in bounded
    grown = failure_message(ts.UNDERFLOW, (0.99, 1e-16), False, np.array([1e6]), None, None,
                            True, ode, 1000)
    assert "may blow up" in grown and "1e+06-fold since t0" in grown


def test_a_step_floor_far_from_t_zero_says_to_shift_the_origin():
    """dG(1) at 1e-8 on [1e12, 1e12 + 10] needs steps below the 0.01 that double precision
    resolves at t = 1e12: the stiff-problem advice alone misled; the origin is the cause."""
    x, v = sp.symbols("x v")
    ode = dn.ODE({x: v, v: -x}, u0=[1.0, 0.0], t0=1e12, T=1e12 + 10.0)
    with pytest.raises(dn.SolverError, match=r"far from t = 0 .* t0 = 0 and T = 10 "):
        dn.solve(ode, "dG(1)", tolerance=1e-8)
    sol = dn.solve(dn.ODE({x: v, v: -x}, u0=[1.0, 0.0], T=10.0), "dG(1)", tolerance=1e-8)
    assert abs(sol(10.0)[0] - np.cos(10.0)) < 1e-7


def test_a_logarithmic_singularity_is_named_as_a_possible_singularity_of_f():
    """u' = 1 / (0.5 - t): u = -log(1 - 2t) grows to only about 30 before the steps reach
    the rounding floor at t = 0.5; the failure names a singularity of f, not only stiffness."""
    ode = dn.ODE({u: 1 / (0.5 - dn.t)}, u0=[0.0], T=1.0)
    with pytest.raises(dn.SolverError, match="singular") as raised:
        dn.solve(ode, "dG(1)", tolerance=1e-6)
    assert "t = 0.5" in str(raised.value)
