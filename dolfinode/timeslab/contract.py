"""The contract between the driver and the time-slab loops: their options and their state,
each a numpy record array of one element with named fields (a numba record in the loops).

A loop reads ``options[0].rtol``, carries ``state[0].t`` from one call to the next; the driver
fills both in one place (:func:`dolfinode.solve.solve_lowered` and its ``_run_*``) and reads
``state["t"][0]``. One dtype each serves the mono- and the multi-adaptive loop, so every loop
is compiled for one signature; a field a loop does not use stays at its default.

Options (set before a loop runs; the piecewise driver of :mod:`dolfinode.events` moves ``T``):

=================  ====================================================================
solver             nonlinear solver, index into parameters.NONLINEAR_SOLVERS (DEFAULT,
                   FIXED_POINT, NEWTON of :mod:`dolfinode.timeslab`)
fixed              fixed time steps (no error control)
max_iter           most nonlinear iterations per slab (global iterations: multi)
is_dg              the method is dG(q) (its first node is a stage)
newton_ready       mono: the storage of the Newton matrices is decided and fits (else the
                   loop returns NEWTON_NEEDED when it first needs them)
reuse              mono: a factorization costs enough to keep it over slabs (REUSE_TIME)
keep_factors       mono: keep the factors over slabs of their step while Newton contracts
                   fast (THETA_KEEP; set with reuse, or by mono.KEEP_FACTORS)
band_lower/upper   multi: the band widths of df/du in the bandwidth ordering
autonomous         multi: f does not depend on t
rtol               relative tolerance (atol is an array argument)
T                  end time of this call
kmax               largest step
safety             safety factor of the step control
dtol               discrete (iteration) tolerance, relative to the tolerance
delivered          the error at T the tolerance delivers, in units of rtol (tolerance /
                   rtol; 1 uncalibrated, 0: none): mono, Newton's stop
                   (slab.newton_tolerance); multi, the scale of the interior estimates
                   (multi.control.interior_indicators)
order              P in the error estimate eps = O(k^P)
span               T - t0 of the whole solve (the step floor, the iteration tolerance)
gamma              the error filter's constant |det A|^(1/S) (dolfinode.adaptivity)
loosening          log(step tolerance / (c tolerance)) of the calibration, taken back
                   on stiff components (adaptivity.stiff_factor; 0: none)
newton_units       mono: a Newton iteration's cost in f evaluations (mono.newton_costs)
factor_units       mono: a Jacobian with its factorizations, in f evaluations
theta, beta        multi: partitioning and interval thresholds (partition.build_slab)
unfused            multi: no fused path for synchronised slabs (every component on one
                   step): they are built, solved and stored as any slab (tests compare)
=================  ====================================================================

State (kept by the driver across calls, and saved/restored by the piecewise driver):

=================  ====================================================================
t                  the current time
k_next             mono: the next step
eps_prev           mono: the last accepted error estimate (PI controller)
k_accepted         mono: the last accepted step (predictive controller; 0: none yet)
have_f0            mono: f(x, t) is in the f0 argument
fp_step            mono: the last step fixed-point iteration converged on (0: none)
fp_iterations      mono: running mean of fixed-point iterations per slab
newton_cost        mono: running mean of Newton's cost per slab in f evaluations
k_newton           mono: Newton's step when it gave way to fixed point (0: it has not)
mono_elements      multi: elements a mono-adaptive method with each slab's smallest step
                   would have needed (the efficiency index)
deviation          calibrated runs: the largest distance of a stiff component from its
                   quasi-steady state relative to itself (adaptivity.stiff_deviation)
last_deviation     the same on the last slab, of the component ``deviated``, whose estimate
                   is ``deviation_error`` x its step tolerance there
interior           multi, calibrated runs: the largest interior estimate of an accepted
interior_of        slab in units of the tolerance as given, its component and time
interior_at        (multi.control.interior_indicators)
carried            the loop's carried state below and its ``carried`` arrays hold (False: a
                   fresh start, set by start and by a restart of the events' driver)
k_solver           mono: the largest step the nonlinear solver is trusted with: its last
                   failure's, raised by NEWTON_PROBE per accepted step
k_accuracy         mono: the step the error control asks for (solver failures aside)
k_last             mono: the step of the last slab in the carried arrays (0: none)
k_factored         mono: the step chosen for the carried factors, before its rounding to the
                   slab t + k represents (0: none)
theta              mono: Newton's contraction rate with them (inf: unknown)
newton_rate        mono: Newton's contraction rate on the last slab it solved
age                mono: Newton slabs since the Jacobian was evaluated
filter_ok          mono: the carried error filter's factors are usable
k_slab             multi: the slab length limit (steps.slab_limit)
hold               multi: accepted slabs before the limit may grow after a rejection
climb_cost         multi: the last slab's cost per unit time, and the direction
climb_direction    of the limit's climb (steps.slab_limit)
sync_fail          multi: slabs are synchronised only below this length (loop.SYNCHRONISE_PROBE)
jacobian_age       multi: synchronised slabs since the Jacobian rows were evaluated
regroup            multi: the active set changed (its Jacobian rows are all evaluated anew)
synchronised       multi: the last slab was solved synchronised
f0_time            multi: the time at which the carried f(x, t) holds (NaN: none)
outside            multi: the component that left its domain on the last slab, or -1
retry              multi: the last slab was rejected; the carried attempt guesses its retry
=================  ====================================================================

Each loop carries all it needs from one call to the next in the state and its ``carried``
arrays (:func:`dolfinode.timeslab.mono.carry`, :func:`dolfinode.timeslab.multi.loop.carry`),
so that a run cut into calls by its output buffers steps as one call would, whatever their
size.
"""
import itertools

import numba
import numpy as np

OPTIONS = np.dtype([
    ("solver", np.int64), ("max_iter", np.int64), ("band_lower", np.int64),
    ("band_upper", np.int64), ("rtol", np.float64), ("T", np.float64), ("kmax", np.float64),
    ("safety", np.float64), ("dtol", np.float64), ("order", np.float64), ("span", np.float64),
    ("gamma", np.float64), ("loosening", np.float64), ("newton_units", np.float64),
    ("factor_units", np.float64), ("delivered", np.float64),
    ("theta", np.float64), ("beta", np.float64), ("fixed", np.bool_), ("is_dg", np.bool_),
    ("newton_ready", np.bool_), ("reuse", np.bool_), ("keep_factors", np.bool_),
    ("autonomous", np.bool_), ("unfused", np.bool_)], align=True)
STATE = np.dtype([
    ("t", np.float64), ("k_next", np.float64), ("eps_prev", np.float64),
    ("fp_step", np.float64), ("fp_iterations", np.float64), ("newton_cost", np.float64),
    ("k_newton", np.float64), ("mono_elements", np.float64), ("deviation", np.float64),
    ("last_deviation", np.float64), ("deviation_error", np.float64), ("deviated", np.int64),
    ("k_accepted", np.float64), ("k_slab", np.float64), ("climb_cost", np.float64),
    ("climb_direction", np.float64), ("sync_fail", np.float64), ("f0_time", np.float64),
    ("hold", np.int64), ("jacobian_age", np.int64), ("outside", np.int64),
    ("k_solver", np.float64), ("k_accuracy", np.float64),
    ("newton_rate", np.float64), ("k_last", np.float64),
    ("k_factored", np.float64), ("theta", np.float64), ("age", np.int64),
    ("interior", np.float64), ("interior_at", np.float64), ("interior_of", np.int64),
    ("filter_ok", np.bool_),
    ("have_f0", np.bool_), ("carried", np.bool_), ("regroup", np.bool_),
    ("synchronised", np.bool_), ("retry", np.bool_)], align=True)

#: Their numba types, for the loops' signatures.
OPTIONS_TYPE = numba.from_dtype(OPTIONS)[::1]
STATE_TYPE = numba.from_dtype(STATE)[::1]


def _record(dtype, values):
    """A record array of one element of ``dtype`` with the given field ``values`` (taken
    out of the dict), the other fields zero."""
    # one assignment of all fields (by name each costs as much as the whole tuple), into
    # zeroed bytes (np.zeros of a record dtype costs 5x more)
    record = np.frombuffer(bytearray(dtype.itemsize), dtype=dtype)
    if not values:  # (the bytes are zero already)
        return record
    record[0] = tuple(map(values.pop, dtype.names, itertools.repeat(0)))
    if values:
        raise TypeError(f"no field {next(iter(values))!r} in {dtype.names}")
    return record


def options(**values):
    """The options of a loop: a record array of one element, unnamed fields zero (False)."""
    return _record(OPTIONS, values)


def state(**values):
    """The state of a loop: a record array of one element, unnamed fields zero (False)."""
    return _record(STATE, values)
