"""dn.Solver: validated once, then solves as dn.solve does, with the values of each call."""
import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.compile.jit import Loop

u, v, k = sp.symbols("u v k")


@pytest.fixture(autouse=True)
def checked_loops(monkeypatch):
    """Type-check every call of a compiled loop: the drivers must pass the loops' exact
    argument types, which their unchecked calls assume."""
    monkeypatch.setattr(Loop, "checked", True)


@pytest.fixture
def oscillator():
    return dn.ODE({u: v, v: -k * u}, u0={u: 1.0, v: 0.0}, T=2.0, params={k: 4.0})


@pytest.mark.parametrize("method", ["cG(2)", "dG(2)", "mcG(1)"])
def test_solver_is_bitwise_dn_solve_of_the_varied_ode(oscillator, method):
    solver = dn.Solver(oscillator, method=method, tolerance=1e-6)
    sol = solver.solve(u0=[0.5, 0.0], params={k: 9.0}, T=1.5)
    reference = dn.solve(dn.vary(oscillator, {"u0": [0.5, 0.0], k: 9.0, "T": 1.5}),
                         method=method, tolerance=1e-6)
    np.testing.assert_array_equal(sol.values, reference.values)
    np.testing.assert_array_equal(sol.t_start, reference.t_start)
    assert sol.stats["f evaluations"] == reference.stats["f evaluations"]


def test_solver_follows_the_parameters_of_each_call(oscillator):
    solver = dn.Solver(oscillator, method="dG(2)", tolerance=1e-8)
    for omega in (3.0, 1.0, 2.0):  # u = u0 cos(omega t) for k = omega^2
        sol = solver.solve(u0=[0.5, 0.0], params={k: omega**2})
        assert sol.ode.params[k] == omega**2
        assert sol(2.0)[0] == pytest.approx(0.5 * np.cos(2.0 * omega), abs=1e-6)
    # the declaration itself is left as it was; by name works as by symbol
    assert oscillator.params[k] == 4.0 and oscillator.T == 2.0
    by_name = solver.solve(params={"k": 4.0})
    np.testing.assert_array_equal(by_name.values, dn.solve(oscillator, method="dG(2)",
                                                           tolerance=1e-8).values)


def test_solver_times_and_estimate_error_use_the_call_values(oscillator):
    solver = dn.Solver(oscillator, method="cG(2)", tolerance=1e-8)
    sol = solver.solve(t0=1.0, T=3.0, params={k: 1.0}, u0=[1.0, 0.0])
    assert sol.t[0] == 1.0 and sol.t[-1] == 3.0
    assert sol(3.0)[0] == pytest.approx(np.cos(2.0), abs=1e-6)
    est = dn.estimate_error(sol, goal={u: 1.0})
    assert abs(est.value) < 1e-6


def test_solver_rejects_bad_input_up_front_and_per_call(oscillator):
    with pytest.raises(TypeError):
        dn.Solver("not an ode")
    with pytest.raises(ValueError, match="tolerance"):
        dn.Solver(oscillator, tolrance=1e-6)
    with pytest.raises(ValueError):
        dn.Solver(oscillator, method="xG(2)")
    solver = dn.Solver(oscillator, method="cG(1)")
    with pytest.raises(ValueError):
        solver.solve(params={sp.Symbol("q"): 1.0})
    with pytest.raises(ValueError):
        solver.solve(u0=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        solver.solve(T=-1.0)
