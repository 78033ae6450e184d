"""The averaging kernel: independent of the phase and of whole periods in the window, and of
fourth order (a slow cubic is averaged to its value at the centre)."""
from types import SimpleNamespace

import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode.compile import lower
from dolfinode.modeling import average_window, kernel_weights
from dolfinode.modeling.averaging import WindowAverager


def test_weights_normalised_and_symmetric():
    w = kernel_weights(100)
    assert w.size == 201 and w.sum() == pytest.approx(1.0) and np.allclose(w, w[::-1])
    assert w[0] == pytest.approx(0.0, abs=1e-30)


def test_kernel_is_of_fourth_order():
    """Zero second moment: the average of a cubic is its value at the centre, and a smooth
    slow function is shifted by O(tau^4), not by the O(tau^2) of a positive kernel."""
    w = kernel_weights(500)
    s = np.linspace(-1.0, 1.0, w.size)
    assert s**2 @ w == pytest.approx(0.0, abs=1e-15)
    c = np.array([0.3, -1.2, 2.5, 0.7])
    assert np.polyval(c, 0.2 + s) @ w == pytest.approx(np.polyval(c, 0.2), abs=1e-14)
    shifts = [abs(np.cos(1.0 + tau * s) @ w - np.cos(1.0)) for tau in (0.4, 0.2)]
    assert shifts[0] / shifts[1] == pytest.approx(16.0, rel=0.02)


@pytest.mark.parametrize("periods", [15.0, 15.25, 15.5, 16.37])
def test_average_of_cos_squared_is_one_half_for_any_window(periods):
    # omega tau = 2 pi periods ~ 100, the simple model's setting; a box average would be off
    # by up to 1 / (4 omega tau) ~ 2.5e-3 depending on the fraction of a period
    omega, tau = 2 * np.pi * periods, 1.0
    s = tau * np.linspace(-1.0, 1.0, 2001)
    w = kernel_weights(1000)
    box_errors = []
    for phase in (0.0, 0.3, 1.1):
        # the kernel's transform at 2 omega tau ~ 190 is ~ 1e-11 (the Hann kernel: 1e-6)
        assert abs(np.cos(omega * s + phase) ** 2 @ w - 0.5) < 1e-9
        box_errors.append(abs(np.mean(np.cos(omega * s[:1001] + phase) ** 2) - 0.5))
    if periods % 0.5:  # not a whole number of periods of cos^2 in the box [-tau, 0]
        assert max(box_errors) > 1e-4


def test_window_averaged_piece_by_piece_equals_the_whole_window():
    """WindowAverager fed a window in consecutive pieces gives the averages of the whole
    window to rounding; the averaging times at a piece end are read once."""
    u, v = sp.symbols("u v")
    ode = dn.ODE({u: v, v: -400 * u}, u0=[1.0, 0.0], T=2.0)
    tau, samples = 1.0, 100
    whole = dn.solve(ode, method="cG(2)", tolerance=1e-8)
    compiled = lower(ode)
    expected = average_window(whole, compiled, tau, tau, samples)

    class Piece:  # the whole solution on [., T]
        def __init__(self, T):
            self.ode = SimpleNamespace(T=T)

        def __call__(self, t):
            return whole(t)

    averager = WindowAverager(compiled, tau, tau, samples, 0.0, 2.0)
    for T in (0.5, 1.25, 2.0):  # 0.5 and 1.25 are averaging times
        averager.record(Piece(T))
    pieces = averager.averages()
    for name in ("u_bar", "f_bar", "g_bar", "drift", "fluctuation", "amplitude"):
        np.testing.assert_allclose(getattr(pieces, name), getattr(expected, name), rtol=0,
                                   atol=1e-12, err_msg=name)
    assert pieces.center == expected.center == tau


@pytest.mark.parametrize("amplitude", [0.0, 1e-7, 3e-3])
def test_amplitude_of_a_fast_oscillation_about_a_slow_trend(amplitude):
    """u = 1 + t - t^2 / 3 + exp(t) / 5 + a sin(omega t + 0.4) on a window: the amplitude is a
    within 2 % (the slow trend leaves below 1e-9), whatever the slow part; f is not read."""
    omega, tau, center = 377.0, 0.1, 0.7

    class Piece:
        ode = SimpleNamespace(T=center + tau)

        def __call__(self, t):
            return np.array([1 + t - t**2 / 3 + np.exp(t) / 5
                             + amplitude * np.sin(omega * t + 0.4)])

    u = sp.symbols("u")
    averager = WindowAverager(lower(dn.ODE({u: -u}, u0=[1.0], T=1.0)), center, tau, 1000,
                              0.0, 1.0)
    averager.record(Piece())
    measured = averager.averages().amplitude[0]
    assert measured == pytest.approx(amplitude, rel=0.02, abs=1e-9)


@pytest.mark.parametrize("subgrid_model", ["constant", "affine", "auto"])
def test_fast_component_at_rest_has_zero_drift_and_is_inactivated(subgrid_model):
    # u2 at rest (x0 = v0 = 0) had drift inf: "constant" and "affine" refused it as moving
    u1, u2, k = sp.symbols("u1 u2 kappa")
    ode = dn.ODE.second_order({u1: -u1 + u2**2 / 2 + 1, u2: -k * u2},
                              x0={u1: 0.0, u2: 0.0}, v0={u1: 0.0, u2: 0.0}, T=20.0,
                              params={k: 1e8})
    sol = dn.solve(ode, "cG(2)", tolerance=1e-4, automatic_modeling=True,
                   average_length=1e-2, subgrid_model=subgrid_model)
    assert set(sol.model.inactive) == {ode.states[1], ode.states[3]}
    t = np.linspace(0.0, 20.0, 201)
    assert np.max(np.abs(sol(t)[0] - (1 - np.cos(t)))) < 1e-4
