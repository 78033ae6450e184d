"""The compiled start of a solve: f(u0, t0), the first step, the loop's fresh state."""
import numpy as np
import pytest
import sympy as sp

import dolfinode as dn
from dolfinode import timeslab as ts
from dolfinode.compile import lower
from dolfinode.timeslab import contract
from dolfinode.timeslab.start import (
    F0_NOT_FINITE,
    INTERVAL_UNRESOLVED,
    READY,
    first_step,
    start,
    trial_step,
)

y, z, a = sp.symbols("y z a")


def _start(ode, atol, rtol, guess=True, steps=None, mono=True, T=None, **options):
    """Run the start on ``ode`` with fresh arrays (counters and state dirty, to see them
    reset) and the loop ``options`` given; (status, f0, steps, state, counters)."""
    compiled = lower(ode)
    T = ode.T if T is None else T
    options = contract.options(T=T, span=T - ode.t0, **options)
    state = contract.state(t=-1.0, k_next=7.0, mono_elements=3.0, newton_cost=2.0)
    counters = np.arange(ts.NUM_COUNTERS, dtype=np.int64)
    f0 = np.full(ode.N, np.nan)
    steps = np.empty(ode.N) if steps is None else np.array(steps, dtype=float)
    status = start(compiled.rhs.address, compiled.p, ode.t0, np.full(ode.N, atol), rtol, guess,
                   ode.u0.copy(), f0, steps, options, state, counters, mono)
    return status, f0, steps, state, counters


def test_first_step_is_the_hnw_guess_within_its_bounds():
    x, f, atol = np.array([1.0, -2.0]), np.array([3.0, 0.5]), np.full(2, 1e-6)
    w = 1 / (atol + 1e-3 * np.abs(x))
    guess = 0.01 * np.max(np.abs(x) * w) / np.max(np.abs(f) * w)
    assert first_step(f, x, 0.0, atol, 1e-3, 10.0) == guess
    assert first_step(f, x, 0.0, atol, 1e-3, 1e-4) == 1e-4  # at most the span
    # far from t = 0 at least 4 x the smallest resolvable step (1e-6 span for x = 0 is not)
    zero = np.zeros(2)
    assert first_step(f, zero, 1e9, atol, 1e-3, 5.0) == 4 * ts.smallest_step(1e9, 5.0)


@pytest.mark.parametrize("mono", [True, False])
def test_start_evaluates_f0_guesses_the_step_and_resets_state_and_counters(mono):
    ode = dn.ODE({y: -a * y, z: y}, u0=[2.0, 1.0], T=3.0, params={a: 1.5}, t0=1.0)
    status, f0, steps, state, counters = _start(ode, 1e-6, 1e-4, mono=mono)
    assert status == READY
    np.testing.assert_array_equal(f0, [-3.0, 2.0])
    k = first_step(f0, ode.u0, 1.0, np.full(2, 1e-6), 1e-4, 2.0)
    np.testing.assert_array_equal(steps, [k, k])
    assert not counters.any()
    st = state[0]
    assert (st["t"], st["mono_elements"], st["newton_cost"]) == (1.0, 0.0, 0.0)
    started = (st["k_next"], st["eps_prev"], st["have_f0"], st["fp_iterations"])
    if mono:  # the first step and the controller's start
        assert started == (k, 1.0, True, 6.0)
    else:  # the multi-adaptive loop reads t and its own steps only
        assert started == (0.0, 0.0, False, 0.0)


@pytest.mark.parametrize("mono", [True, False])
def test_dg_start_refines_the_first_step_by_a_trial_euler_step(mono):
    """dG(q) (mono-adaptive) takes HNW's refined first step; cG(q), whose start must resolve
    a transient that f(u0) may not show yet (ROBER), and the multi-adaptive loops keep k0."""
    ode = dn.ODE({y: -a * y, z: y}, u0=[2.0, 1.0], T=3.0, params={a: 1.5})
    atol = np.full(2, 1e-6)
    _, f0, steps, _, _ = _start(ode, 1e-6, 1e-4, mono=mono, is_dg=True, order=4.0)
    k0 = first_step(f0, ode.u0, 0.0, atol, 1e-4, 3.0)
    k = trial_step(lower(ode).rhs.address, lower(ode).p, 0.0, atol, 1e-4, ode.u0, f0, k0, 4.0,
                   3.0)
    assert k > k0
    np.testing.assert_array_equal(steps, [k, k] if mono else [k0, k0])
    assert _start(ode, 1e-6, 1e-4, is_dg=False, order=4.0)[2][0] == k0


def test_start_keeps_given_steps():
    ode = dn.ODE({y: -y, z: y}, u0=[1.0, 0.0], T=1.0)
    status, _, steps, state, _ = _start(ode, 1e-6, 1e-6, guess=False, steps=[0.01, 0.02])
    assert status == READY
    np.testing.assert_array_equal(steps, [0.01, 0.02])
    assert state["k_next"][0] == 0.01


def test_start_reports_what_fails():
    ode = dn.ODE({y: 1 / y}, u0=[0.0], T=1.0)
    assert _start(ode, 1e-6, 1e-6)[0] == F0_NOT_FINITE
    # each f_i finite, their sum not: not a failure
    big = dn.ODE({y: 1e308 * (1 + 0 * y), z: 1e308 * (1 + 0 * z)}, u0=[1.0, 1.0], T=1.0)
    assert _start(big, 1e-6, 1e-6)[0] == READY
    late = dn.ODE({y: -y}, u0=[1.0], t0=1e15, T=1e15 + 1)
    assert _start(late, 1e-6, 1e-6)[0] == INTERVAL_UNRESOLVED
