"""The smallest resolvable step (dolfinode.timeslab.smallest_step) on long intervals."""
import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.timeslab import smallest_step

u, v = sp.symbols("u v")


def test_smallest_step_is_relative_to_t_not_to_the_interval():
    assert smallest_step(0.0, 1e13) <= 1e-20
    assert smallest_step(1e13, 1e13) == pytest.approx(1e-14 * 1e13, rel=1e-6)
    assert smallest_step(1e-9, 1e13) < 1e-18  # a step of 1e-12 at t = 1e-9 is resolved


@pytest.fixture(scope="module")
def kinetics():
    """A fast layer at t ~ 1e-9 (u = exp(-1e9 t)), then v = 1 / (1 + 1e9 t) decays over
    thirteen decades to 1e-22 at T = 1e13: the first step must be near 1e-9."""
    return dn.ODE({u: -1e9 * u, v: -1e9 * v**2}, u0=[1.0, 1.0], T=1e13)


@pytest.mark.parametrize("method", ["cG(2)", "dG(2)", "mdG(2)"])
@pytest.mark.parametrize("tol", [1e-5, 1e-8, 1e-10])
def test_long_interval_with_fast_start_meets_tolerance(kinetics, method, tol):
    # (every method raised "the time step fell to 7.2e-09 at t = 0" with the floor
    # 1e-14 max(|t|, 1e-6 T))
    atol = 1e-24
    # values inside elements (O(k^(q+1))) within 10 x: the local estimate bounded by tol
    sol = dn.solve(kinetics, method=method, tolerance=tol, absolute_tolerance=atol,
                   calibrate_tolerance=False)
    times = np.array([1e-9, 1e-6, 1.0, 1e6, 1e13])
    exact = np.array([np.exp(-1e9 * times), 1 / (1 + 1e9 * times)])
    assert np.all(np.abs(sol(times) - exact) <= 10 * (tol * np.abs(exact) + atol))
