"""Finite-time blow-up and non-finite right-hand sides raise SolverError; nothing non-finite is
ever returned."""
import time

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn

METHODS = ["cG(1)", "cG(2)", "dG(0)", "dG(1)", "dG(2)", "mcG(1)", "mdG(1)"]


@pytest.mark.parametrize("method", METHODS)
def test_blowup_raises_near_t_1(method):
    """u' = u^2, u(0) = 1 blows up at t = 1 (u = 1 / (1 - t)). dG(0), of order 1, runs at
    tolerance 1e-4: at 1e-6 it needs millions of slabs to get there (measured 4-16 s)."""
    u = sp.Symbol("u")
    ode = dn.ODE({u: u**2}, u0=[1.0], T=2.0)
    dn.solve(dn.ODE({u: -u}, u0=[1.0], T=0.1), method=method)  # compiles the loop, if needed
    start = time.perf_counter()
    with pytest.raises(dn.SolverError, match="t = ") as info:
        dn.solve(ode, method=method, tolerance=1e-4 if method == "dG(0)" else 1e-6)
    assert time.perf_counter() - start < 10.0
    assert 0.98 < info.value.t <= 1.0 + 1e-5


@pytest.mark.parametrize("method", METHODS)
def test_square_root_of_a_negative_number_is_never_returned(method, finite):
    """u' = -sqrt(u), u(0) = 1: u = (1 - t/2)^2 reaches 0 at t = 2, after which sqrt(u) of a
    slightly negative iterate is NaN. A returned solution must be finite and close to the
    exact one; otherwise SolverError."""
    u = sp.Symbol("u")
    ode = dn.ODE({u: -sp.sqrt(u)}, u0=[1.0], T=3.0)
    try:
        sol = dn.solve(ode, method=method, tolerance=1e-6, maximum_steps=100_000)
    except dn.SolverError:
        return
    finite(sol)
    ts = np.linspace(0.0, 1.9, 20)
    np.testing.assert_allclose(sol(ts)[0], (1 - ts / 2) ** 2, atol=1e-3)
