"""The start of a solve, compiled: f(u0, t0), the first step and the loop's fresh state, in
one call from the driver (as numpy operations on arrays of a few elements, each its own
call from Python, they were most of the time of a small solve).

:func:`start` is called once per solve, by :func:`dolfinode.solve` and
:class:`dolfinode.Solver` alike, before the first call of a time-slab loop; the checks it
finds failing are raised by the driver, which words them (:data:`F0_NOT_FINITE`,
:data:`INTERVAL_UNRESOLVED`).
"""
import math

import numpy as np
from numba import types

from dolfinode.adaptivity import initial_step, refined_step
from dolfinode.compile.jit import Loop, helper
from dolfinode.compile.signatures import call_rhs
from dolfinode.timeslab import smallest_step
from dolfinode.timeslab.contract import OPTIONS_TYPE, STATE_TYPE

#: Return codes of :func:`start`: ready, f(u0, t0) not finite, [t0, T] shorter than the
#: smallest step double precision resolves there.
READY, F0_NOT_FINITE, INTERVAL_UNRESOLVED = range(3)
#: The running mean of fixed-point iterations per slab (mono) starts at a typical 6.
FIXED_POINT_ITERATIONS = 6.0


@helper()
def first_step(f, x, t, atol, rtol, span):
    """The first step of a start at (x, t), f = f(x, t): Hairer-Noersett-Wanner's guess
    (:func:`dolfinode.adaptivity.initial_step`), at least 4 x the smallest step resolvable
    at t (far from t = 0 the guess 1e-6 span for x = 0 can be below it), at most the span."""
    return min(max(initial_step(f, x, atol, rtol, span), 4 * smallest_step(t, span)), span)


@helper()
def trial_step(rhs, p, t0, atol, rtol, x, f0, k0, order, span):
    """The first step refined by a trial explicit Euler step of length k0
    (:func:`dolfinode.adaptivity.refined_step`); k0 where f there is not finite."""
    x1 = x + k0 * f0
    f1 = np.empty(f0.shape[0])
    call_rhs(rhs, x1, t0 + k0, p, f1)
    return refined_step(k0, f0, f1, x, atol, rtol, order, span)


def _start(rhs, p, t0, atol, rtol, guess, x, f0, steps, options, state, counters, mono):
    """f0 = f(x, t0) from the kernel at address ``rhs``; if ``guess``, every entry of
    ``steps`` the :func:`first_step` for ``atol``, ``rtol``, refined by :func:`trial_step`
    for mono-adaptive dG(q) (else ``steps`` as given; cG(q) is not L-stable: its start must
    resolve a transient that f(x, t0) may not show yet, as ROBER's); the loop's ``state`` at
    t0 (mono: the first step and the controller's start) and zero ``counters``. Reads T and the span
    T - t0 from ``options``. Returns READY, or the first check that fails: F0_NOT_FINITE,
    INTERVAL_UNRESOLVED."""
    call_rhs(rhs, x, t0, p, f0)
    total = 0.0
    for value in f0:
        total += value
    if not math.isfinite(total):  # (a sum may overflow where every value is finite)
        for value in f0:
            if not math.isfinite(value):
                return F0_NOT_FINITE
    op = options[0]
    span = op.span
    if guess:
        steps[:] = first_step(f0, x, t0, atol, rtol, span)
        if mono and op.is_dg and steps[0] < span:
            steps[:] = min(trial_step(rhs, p, t0, atol, rtol, x, f0, steps[0], op.order, span),
                           span)
    if span < smallest_step(max(abs(t0), abs(op.T)), span):
        return INTERVAL_UNRESOLVED
    counters[:] = 0
    st = state[0]
    st.t = t0
    st.k_next = steps[0] if mono else 0.0
    st.eps_prev = 1.0 if mono else 0.0
    st.have_f0 = mono
    st.fp_iterations = FIXED_POINT_ITERATIONS if mono else 0.0
    st.fp_step = st.newton_cost = st.k_newton = st.mono_elements = st.k_accepted = 0.0
    st.deviation = st.last_deviation = st.interior = 0.0
    st.carried = False  # (the multi-adaptive loop starts its carried state afresh)
    return READY


_f8 = types.float64[::1]
start = Loop(_start, types.int64(types.intp, _f8, types.float64, _f8, types.float64,
                                 types.boolean, _f8, _f8, _f8, OPTIONS_TYPE, STATE_TYPE,
                                 types.int64[::1], types.boolean),
             "the start of a solve", 2)
