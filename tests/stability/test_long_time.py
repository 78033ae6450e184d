"""Long-time behaviour on the harmonic oscillator u' = v, v' = -u over 10^4 periods.

Theory: for a linear system, cG(q) conserves the energy |U|^2 at the nodes exactly (it is
energy-conserving when the discrete equations are solved exactly) and dG(q) dissipates it
monotonically. Measured over 10^3 periods at tolerance 1e-6: with Newton (exact for a linear
system) cG(2) and cG(3) keep |E - 1| below 3e-14 and dG(2) decays monotonically. With the
default fixed-point iteration, stopped at discrete_tolerance_factor = 1e-3 of the step
tolerance, the energy drifts linearly in time: cG(2) loses 1.2e-6 per 100 periods, cG(3) and
dG(2) *gain* energy (E(T) = 1.000012 and 1.000069 after 10^3 periods).
"""
import numpy as np
import pytest

import dolfinode as dn
from dolfinode.bench import problems as P

PERIODS = 10_000


def energies(sol):
    """|U(t_n)|^2 at the element end points."""
    return np.sum(sol.values[:, -1, :] ** 2, axis=1)


@pytest.fixture(scope="module")
def oscillator():
    ode, _ = P.harmonic(T=2 * np.pi * PERIODS)
    return ode


@pytest.mark.parametrize("method", ["cG(2)", "cG(3)"])
def test_cg_energy_error_is_bounded(oscillator, method, finite):
    sol = dn.solve(oscillator, method=method, tolerance=1e-6, nonlinear_solver="newton")
    finite(sol)
    E = energies(sol)
    tenth = len(E) // 10
    first, last = np.abs(E[:tenth] - 1).max(), np.abs(E[-tenth:] - 1).max()
    assert np.abs(E - 1).max() < 1e-12
    assert last <= 10 * first + 1e-13, "energy error grows with time"


@pytest.mark.parametrize("method", ["dG(2)", "dG(3)"])
def test_dg_energy_decays_monotonically(oscillator, method, finite):
    sol = dn.solve(oscillator, method=method, tolerance=1e-6, nonlinear_solver="newton")
    finite(sol)
    E = energies(sol)
    assert np.all(np.diff(E) <= 1e-14), "dG energy increased"
    assert E[-1] < 1.0


DRIFT = ("default fixed-point iteration stops at 1e-3 x the step tolerance; its error "
         "accumulates: measured energy drift 1.2e-5 (cG(2)) and gain 6.9e-5 (dG(2)) over 10^3 "
         "periods at tolerance 1e-6")


@pytest.mark.xfail(strict=True, reason=DRIFT)
@pytest.mark.parametrize("method", ["cG(2)", "dG(2)"])
def test_default_solver_keeps_the_energy_behaviour(method):
    ode, _ = P.harmonic(T=2 * np.pi * 1000)
    E = energies(dn.solve(ode, method=method, tolerance=1e-6))
    if method.startswith("cG"):
        assert np.abs(E - 1).max() < 1e-9
    else:
        assert np.all(np.diff(E) <= 1e-14)
