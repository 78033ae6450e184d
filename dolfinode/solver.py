"""A prepared solver for many small solves of one declaration (parameter fits, sweeps).

``Solver(ode, method, **parameters)`` checks the method and the parameters and lowers the
ODE once; ``solver.solve(u0=, params=, T=, t0=)`` then solves with those values replaced,
exactly as :func:`dolfinode.solve` solves :func:`dolfinode.vary` (ode, values): the same
steps and values, bit for bit. The parameter values reach the compiled kernels as the
vector ``p`` of each call, never through the declaration the solver was made from.

A solve without events, breakpoints, switches or automatic modeling, with its history in
memory (and for cG/dG a Newton matrix storage decided: a sparse system's once a solve has
analysed it, the solver's own first call where none did), takes the prepared path: the solver keeps, per
interval [t0, T], a work space (its own kernels, the options and tolerances, the arrays of
the start and of the loop, and output buffers as large as the first ones of dn.solve) and
the loop's whole argument tuple; a call writes the values that changed into it, runs the
compiled start of dn.solve (:mod:`dolfinode.timeslab.start`) and calls the loop once (for
cG/dG in one compiled call, :mod:`dolfinode.timeslab.prepared`), and
the Solution shares the used part of the buffers until it is read or the next call writes
them (:class:`~dolfinode.solution.PreparedSolution`). A call's u0 and parameter values are
checked as the declaration checks them, floats directly; values equal to the last call's
are taken as they were checked then, and what depends on them (p, the floor of the values,
the steps' bound of an f(t) that oscillates in t, the warnings read from u0) is made again
only when they change (the floor only when the parameters' signs or the sign of u0 do). A
mono-adaptive Solution's ``ode`` (the declaration as solved) and ``stats`` are made when
first read. Narrow features of f(t) (breakpoints), everything else, and a solve that
outgrows the buffers or fails, go through the general path
(``solve_lowered``, the driver of dn.solve). dn.solve itself keeps Solvers for options it
was called with before (:mod:`dolfinode.kept`).
"""
import math
import time
import weakref
from collections import namedtuple
from collections.abc import Mapping
from functools import partial
from threading import get_ident
from types import MappingProxyType

import numpy as np

from dolfinode import timeslab as ts
from dolfinode.adaptivity import UNDAMPED_DEVIATION
from dolfinode.ensemble import parameter_symbol, vary
from dolfinode.family import auto_base
from dolfinode.features import narrow_features
from dolfinode.io import history
from dolfinode.linalg.newton_matrix import sparse_candidate
from dolfinode.methods import parse_method
from dolfinode.ode import ODE, Parameters, _parameter_value
from dolfinode.parameters import check_parameters
from dolfinode.solution import PreparedSolution, dense_rhs
from dolfinode.solve import (
    MIN_TOLERANCE,
    _absolute_tolerance,
    _check_resolvable_tolerance,
    _check_start,
    _completed_stats,
    _floor,
    _has_negative,
    _has_zero,
    _initial_steps,
    _largest_step,
    _mono_arguments,
    _mono_capacity,
    _mono_stats,
    _multi_arguments,
    _multi_buffers,
    _multi_capacity,
    _multi_stats,
    _multi_workspace,
    _newton_options,
    _options,
    _signs,
    _warn_interior,
    _warn_undamped,
    below_tolerance,
    check_error_at_T,
    check_tolerance,
    checks_at_T,
    fewest_checked_steps,
    lower,
    lowered,
    note_step_bound,
    run_started,
    solve,
    solve_lowered,
    starts_below_tolerance,
    warn_below_tolerance_throughout,
    warn_growth,
    warn_lost_components,
    warn_spanned_growth,
)
from dolfinode.timeslab import contract, mono, prepared
from dolfinode.timeslab.start import READY, start

#: Longest u0 of a call checked value by value in Python; a longer one is checked as an array.
_DIRECT_U0 = 64


class Solver:
    """Solve one ODE declaration many times with other initial values, parameters or times.

    Parameters
    ----------
    ode : ODE or TemplateODE
    method : str
        As for :func:`dolfinode.solve` ("cG(q)", "dG(q)", "mcG(q)", "mdG(q)", "auto"; "auto"
        chooses anew on every call, through :func:`dolfinode.solve`).
    **parameters
        As for :func:`dolfinode.solve` (DOLFIN's names); checked here, once.

    Raises
    ------
    TypeError, ValueError
        For an invalid ODE, method or parameter (with the closest valid name).

    Notes
    -----
    A Solver keeps work space between calls (its copy of the declaration, the loop's output
    buffers) for the thread of its first call; calls from other threads solve a new copy of
    the declaration by the general path of :func:`dolfinode.solve` (the same results,
    without the prepared path's savings): make one Solver per thread for parallel fits.
    The Solutions it returns are left alone by later calls: a mono-adaptive one reads the
    output buffers until it is read or the next call writes them, which copies them first
    (:class:`~dolfinode.solution.PreparedSolution`).

    Examples
    --------
    >>> solver = dn.Solver(ode, method="dG(2)", tolerance=1e-8)      # doctest: +SKIP
    >>> sol = solver.solve(u0=[0.5, 0.0], params={k: 9.0})          # doctest: +SKIP
    """

    def __init__(self, ode, method="cG(1)", **parameters):
        self._setup(ode, method, parameters, {})

    def _setup(self, ode, method, parameters, pool):
        """The solver of ``ode`` with ``method`` and ``parameters``, its output buffers taken
        from ``pool`` (shape -> arrays, shared by solvers that are never called at once)."""
        if not isinstance(ode, ODE):
            raise TypeError(f"Solver expects a dolfinode.ODE, got {type(ode).__name__}")
        if "goal" in parameters:
            raise ValueError("Solver solves without a goal: for goal-oriented adaptivity "
                             "call dn.solve(ode, goal=...)")
        base = auto_base(method)
        self._auto = base is not None  # (pilot solves each call: no prepared path)
        self._multi_adaptive, self._method = parse_method(base or method)
        self._params = check_parameters(parameters)
        check_tolerance(self._params)
        self._ode, self._method_text = ode, method
        self._given = MappingProxyType(dict(parameters))
        self._pool = pool
        # {0: the thread whose calls use the pool's buffers and the solver's copy of the
        # declaration}, claimed by the first call (dict.setdefault: atomic); _thread: its copy
        self._owner, self._thread = pool.setdefault("owner", {}), None
        self._continued = 0  # prepared calls that did not end in the kept buffers
        self._driver = self._params["automatic_modeling"] or self._auto  # (many solves a call)
        self._prepare()

    @property
    def ode(self):
        """The declaration solved: its values (params, u0, T) are read at every call."""
        return self._ode

    @property
    def method(self):
        """The method, as given."""
        return self._method_text

    @property
    def parameters(self):
        """The parameters given, read-only (the solver checked and lowered them once): a
        Solver with other parameters is a new Solver."""
        return self._given

    def _prepare(self):
        """Lower the declaration (kept on it for every call) and decide the path; the
        solver's own copy of it, whose values each call replaces."""
        ode, params = self.ode, self._params
        compiled, plan = lowered(ode, params)
        self._declared = ode.params  # a new assignment ode.params = {...} prepares again
        self._symbols, self._n = tuple(ode.params), ode.N
        self._by_name = {s.name: s for s in ode.params}
        self._index = {key: i for i, s in enumerate(self._symbols) for key in (s, s.name)}
        # (the declaration's own symbols by identity: sympy's hash of a symbol is Python code)
        self._by_id = {id(s): i for i, s in enumerate(self._symbols)}
        # the values of the last call (its Parameters, its u0 vector): kept while equal
        self._call_values = self._call_u0 = None
        self._work = object.__new__(type(ode))
        self._work.__dict__.update(ode.__dict__)
        self._work.__dict__.pop("_kept_solvers", None)  # (its solutions would keep them alive)
        self._buffers = self._interval = None
        self._autonomous = ode.autonomous  # (no narrow features of f(t) to look for)
        self._given_steps = params["initial_time_step"] is not None
        self._maximum_steps = params["maximum_steps"]
        # the fewest steps whose error at T check_error_at_T checks (estimate_global_error)
        self._checks = checks_at_T(params)
        self._checked_from = (fewest_checked_steps(params["estimate_global_error"])
                              if self._checks else np.inf)
        # a sparse candidate's Newton storage, decided by its first solve that needs Newton's
        # method: the general path until then, this solver prepared again once it is
        self._awaited_plans = None
        if (plan is None and params["dense_output"] is True and not params["progress"]
                and not params["automatic_modeling"] and not self._auto
                and params["estimate_global_error"] is not True):
            m = self._method
            if self._multi_adaptive:  # (the loop's first buffers, as in _run_multi)
                self._buffers, _ = self._kept_buffers(
                    _multi_buffers(ode, m, _multi_capacity(ode, m)))
            elif (not sparse_candidate(compiled.band_structure)
                  or m.name in compiled.newton_plans):  # (as in _run_mono)
                size = min(_mono_capacity(ode, m), params["maximum_steps"])
                # t and k as the rows of one array: a Solution copies them at once
                (self._times, out_X), self._holder = self._kept_buffers(
                    (((2, size), float), ((size, m.q + 1, ode.N), float)))
                self._buffers = (self._times[0], self._times[1], out_X)
            else:
                self._awaited_plans = compiled.newton_plans  # (shared by lower's copies)

    def _kept_buffers(self, shapes):
        """Output buffers of the given (shape, dtype)s from the pool, made when missing, and
        their holder: [a weak reference to the :class:`~dolfinode.solution.PreparedSolution`
        that shares them, or None], shared with the pool's other solvers."""
        kept = self._pool.get(shapes)
        if kept is None:
            kept = self._pool[shapes] = (
                tuple(np.empty(shape, dtype) for shape, dtype in shapes), [None])
        return kept

    def solve(self, u0=None, params=None, T=None, t0=None):
        """Solve with the given initial values, parameter values and interval (each defaults
        to the declaration's); returns a :class:`~dolfinode.Solution` as
        :func:`dolfinode.solve` does, whose ``sol.ode`` carries the values used.

        Parameters
        ----------
        u0 : dict or sequence, optional
            Initial values by state symbol (or name), or in component order.
        params : dict, optional
            Parameter symbols (or names) -> values; the others keep the declaration's.
        T, t0 : float, optional

        Raises
        ------
        TypeError, ValueError
            For values the declaration would reject (naming the entry).
        SolverError
            As :func:`dolfinode.solve`.
        """
        thread = get_ident()
        if thread != self._thread:
            self._thread = self._owner.setdefault(0, thread)
            if self._thread != thread:
                return self._solve_elsewhere(u0, params, T, t0)
        work = self._declaration(u0, params, T, t0)
        if self._driver:
            return solve(work._snapshot(), self.method, **self.parameters)
        # (narrow features are breakpoints of the general path; an oscillating term's step
        # bound is set in the prepared call)
        if self._buffers is not None and (self._autonomous or not narrow_features(work)):
            return self._solve_prepared(work)
        compiled, plan = lowered(work, self._params)
        sol = solve_lowered(work, compiled, plan, self._multi_adaptive, self._method,
                            self._params)
        sol.parameters = dict(sol.parameters)  # (the solver's own: every call reads them)
        if self._awaited_plans is not None and self._method.name in self._awaited_plans:
            self._prepare()
        return sol

    def _solve_elsewhere(self, u0, params, T, t0):
        """:meth:`solve` from a thread other than the one that owns the work space (which may
        be writing it now, or hold a Solution that shares it): dn.solve of a new copy of the
        declaration with these values, as :func:`dolfinode.vary` makes it (bitwise the
        prepared call's result)."""
        values = tuple(self.ode.params.values()) if params is None else self._parameters(params)
        variation = dict(zip(self._symbols, values))
        for name, value in (("u0", u0), ("T", T), ("t0", t0)):
            if value is not None:
                variation[name] = value
        return solve(vary(self.ode, variation), self.method, **self.parameters)

    def _declaration(self, u0, params, T, t0):
        """The solver's copy of the declaration with the values of this call, checked as
        :func:`dolfinode.vary` checks them (the declaration's values where not given). Its
        ``params`` and ``u0`` are the objects of the last call while their values are equal
        (values with a zero are made anew: 0.0 == -0.0), which is how the prepared call
        sees what changed."""
        ode = self.ode
        if ode.params is not self._declared:
            self._prepare()
        work = self._work
        fields = work.__dict__
        # the declaration's values are checked already: only those given here are
        values = tuple(ode.params.values()) if params is None else self._parameters(params)
        last = self._call_values
        if last is None or values != last[0] or 0.0 in values:
            last = self._call_values = (values, Parameters(zip(self._symbols, values)))
        fields["params"] = last[1]
        fields["u0"] = ode.u0 if u0 is None else self._initial_values(u0)
        if t0 is None and T is None:
            fields["t0"], fields["T"] = ode.t0, ode.T
        else:
            work._set_interval(ode.t0 if t0 is None else t0, ode.T if T is None else T)
        return work

    def _parameters(self, params):
        """The parameter values of a call in the declaration's order: the declaration's,
        with those of ``params`` (by symbol or name) checked as :class:`~dolfinode.ODE`
        checks them; a float is taken as it is once found finite."""
        if type(params) is not dict and not isinstance(params, Mapping):
            raise TypeError("params must be a dict {parameter symbol or name: value}, got "
                            f"{type(params).__name__}")
        values = list(self.ode.params.values())
        for key, value in params.items():
            i = self._by_id.get(id(key))
            if i is None:
                i = self._index.get(key)
                if i is None:
                    i = self._index[parameter_symbol(self._by_name, key)]
            values[i] = (value if type(value) is float and math.isfinite(value)
                         else _parameter_value(self._symbols[i], value))
        return tuple(values)

    def _initial_values(self, u0):
        """u0 of a call as :class:`~dolfinode.ODE` takes it (a read-only float vector): a
        short list, tuple or vector of finite floats (as a fit passes) directly, the vector
        of the last call where the values are equal, anything else through the
        declaration's check, which names what is wrong."""
        values = u0.tolist() if type(u0) is np.ndarray and u0.dtype == float else u0
        work = self._work
        if type(values) in (list, tuple) and len(values) == self._n <= _DIRECT_U0:
            values = tuple(values)
            last = self._call_u0
            if last is not None and values == last[0]:
                return last[1]
            if (all(type(x) is float and math.isfinite(x) for x in values)
                    and not (work._constrained and min(values) < 0)):
                u0 = np.array(values)
                u0.flags.writeable = False
                self._call_u0 = None if 0.0 in values else (values, u0)
                return u0
        work.u0 = u0
        return work.u0

    def _workspace(self, work):
        """The loop's arguments for solves over ``work``'s interval (made again when it
        changes): the solver's own kernels, whose ``p`` each call overwrites, the options and
        tolerances, the start's and the loop's arrays, which each call refills, and the kept
        buffers, and the compiled start's and loop's entry points (mono-adaptive: both in one
        compiled call over one object, :mod:`dolfinode.timeslab.prepared`). The storage of the
        Newton matrices is decided here, once, and the sample times and given steps are
        checked."""
        self._interval = None  # (set last: a call stopped before makes all of it again)
        params, m, multi_adaptive = self._params, self._method, self._multi_adaptive
        compiled = lower(work)
        rtol = params["tolerance"]
        atol = _absolute_tolerance(work, params["absolute_tolerance"], rtol)
        loop_atol, options = _options(work, m, params, multi_adaptive, atol)
        given = _initial_steps(work, params["initial_time_step"], multi_adaptive)
        _check_start(work, params, READY, None, given)  # (the given steps: once per interval)
        n = work.N
        x, f0, floor = np.empty(n), np.empty(n), np.empty(n)
        state = contract.state()
        counters = np.zeros(ts.NUM_COUNTERS, dtype=np.int64)
        if multi_adaptive:
            from dolfinode.timeslab import multi

            tables, steps, frozen = _multi_workspace(work, compiled, m, params, options, given)
            arguments = _multi_arguments(compiled, tables, options, loop_atol, floor, x, steps,
                                         frozen, state, counters, _multi_capacity(work, m))
            advance, structure = multi.advance, None
        else:
            structure, _, _ = _newton_options(compiled, m, options)
            steps, frozen = given.copy(), None
            arguments = _mono_arguments(compiled, structure, mono.method_tables(m), options,
                                        loop_atol, floor, x, f0, state, counters,
                                        mono.carry(n, m, structure,
                                                   bool(options["newton_ready"][0])))
            advance = mono.advance
        self._samples = history.sink(work, m, multi_adaptive, params).samples  # (checked)
        # p, floor, the step bound: written by the next call
        self._values = self._signs = self._u0 = self._floor_key = None
        # an oscillating f(t) bounds the steps by what the parameter values make of it
        self._bounded_steps = (params["maximum_time_step"] is None
                               and not params["fixed_time_step"] and not work.autonomous)
        self._step_bound = None
        # (views of the loop's state, read after every call)
        self._deviation, self._k_next = state["last_deviation"], state["k_next"]
        self._kept = _Kept(compiled, atol, given, x, f0, steps, state, counters, floor, frozen,
                           structure, options, loop_atol)
        self._start = (start.entry(), (compiled.rhs.address, compiled.p, work.t0, atol, rtol,
                                       params["initial_time_step"] is None, x, f0, steps,
                                       options, state, counters, not multi_adaptive))
        self._loop = (advance.entry(), (*arguments, *self._buffers))
        # mono: both in one compiled call, which unboxes one object instead of ~40 arrays
        self._initial = np.empty(n)  # (u0, from which the one compiled call sets x)
        self._prepared = None if multi_adaptive else (prepared.run.entry(), prepared.workspace(
            start.compile(), self._start[1], advance.compile(), self._loop[1], x,
            self._initial, (compiled.jacobian.address, compiled.p, compiled.indptr,
                            compiled.indices, *self._buffers, counters),
            # (runs of more steps, or past maximum_steps, are checked in Python)
            int(min(self._checked_from, self._maximum_steps + 1)) if self._checks else 0))
        self._interval = (work.t0, work.T)

    def _solve_prepared(self, work):
        """The solve of ``work`` as one call of the loop into the kept buffers, a run that
        does not fit them going on into new ones as dn.solve's does (:meth:`_go_on`). What
        depends on the values of the call is made again only when they change
        (:meth:`_take_values`). The Solution shares the used part of the buffers until it is
        read or the next call writes them (:class:`~dolfinode.solution.PreparedSolution`);
        a mono-adaptive one makes its ``ode`` and ``stats`` when first read (the ``makers``
        of :class:`~dolfinode.Solution`)."""
        started = time.perf_counter()
        if (work.t0, work.T) != self._interval:
            self._workspace(work)
        if work.params is not self._values or work.u0 is not self._u0:
            self._take_values(work)
        if self._multi_adaptive:
            return self._solve_multi(work, started)
        holder = self._holder
        if holder[0] is not None:  # the last solution sharing the buffers copies them now
            shared = holder[0]()
            if shared is not None:
                shared._make_elements()
            holder[0] = None
        params, kept = self._params, self._kept
        if self._given_steps:
            kept.steps[:] = kept.given
        run, workspace = self._prepared
        status = run(workspace)
        if status != ts.DONE and status != prepared.MAY_SPAN:
            if status < 0:
                _check_start(work, params, -status, kept.f0, kept.steps)
            return self._go_on(work, status, started)
        counts = kept.counters.tolist()
        if counts[ts.SLABS] > self._maximum_steps:
            return self._go_on(work, ts.DONE, started)
        seconds = time.perf_counter() - started
        m, compiled = self._method, kept.compiled
        if self._deviation[0] > UNDAMPED_DEVIATION:  # (what _warn_undamped reads first)
            _warn_undamped(work, compiled, m, params, kept.options, kept.state, False)
        makers = self._makers.copy()  # (those of the call's values, and its stats)
        makers["stats"] = partial(self._stats, counts, self._k_next.item(), seconds)
        sol = PreparedSolution(m, self._times, self._buffers[2], counts[ts.STORED],
                               self._samples, makers)
        holder[0] = weakref.ref(sol)
        steps = counts[ts.SLABS]
        if steps >= self._checked_from:  # (check_error_at_T's own test, read once)
            check_error_at_T(work, compiled, None, False, m, params, sol, steps)
        elif status == prepared.MAY_SPAN:  # (its growth check alone, begun in the call)
            warn_spanned_growth(work, compiled, m, params, sol)
        # values projected to 0 (:func:`warn_lost_components`): none where none ends at 0
        # (x: the values at the end, sol.values[-1, -1])
        if self._bounded and _has_zero(kept.x):
            warn_lost_components(work, compiled, params, sol)
        if self._below:  # (read when u0 was new)
            warn_below_tolerance_throughout(work, kept.atol, sol)
        return sol

    def _solve_multi(self, work, started):
        """:meth:`_solve_prepared` of a multi-adaptive solver: the compiled start and loop
        in two calls, the Solution from the history sink (its stats made at once: they hold
        arrays of the sink)."""
        params = self._params
        (compiled, atol, given, x, f0, steps, state, counters, _, frozen, _, _,
         _) = self._kept
        if self._given_steps:
            steps[:] = given
        x[:] = self._initial
        started_at, arguments = self._start
        _check_start(work, params, started_at(*arguments), f0, steps)
        frozen.fill(np.nan)  # since when each component is frozen (NaN: active)
        advance, arguments = self._loop
        status = advance(*arguments)
        counts = counters.tolist()
        if status != ts.DONE or counts[ts.SLABS] > self._maximum_steps:
            return self._go_on(work, status, started)
        seconds = time.perf_counter() - started
        m = self._method
        if self._deviation[0] > UNDAMPED_DEVIATION:  # (what _warn_undamped reads first)
            _warn_undamped(work, compiled, m, params, self._kept.options, state, True)
        _warn_interior(work, m, state)
        solved = self._solved
        sink = history.InMemory(work, True, self._samples)
        sink.add(history.filled(self._buffers, counts), float(state["t"][0]))
        stats = _completed_stats(
            _multi_stats(counts, state["mono_elements"].item(), sink.per_component, steps),
            counts, True, m, params, compiled.compile_time, seconds)
        note_step_bound(stats, self._step_bound, solved.T - solved.t0)
        sol = sink.solution(solved.declaration(), m, sink.finish(True), stats, x)
        sol.parameters = dict(params)
        # (check_error_at_T reads the busiest component's steps in the stats)
        check_error_at_T(work, compiled, None, True, m, params, sol)
        if self._bounded:
            warn_lost_components(work, compiled, params, sol)
        if self._below:
            warn_below_tolerance_throughout(work, atol, sol)
        return sol

    def _take_values(self, work):
        """Write the values of ``work`` that changed since the last call into the work
        space: the parameter values into p, and with them the steps' bound under an
        oscillating f(t) (as dn.solve's options set it); u0 into the initial
        values, and the floor of the values where the signs it depends on changed; then
        the checks and warnings of new values. First the declaration as solved, then with
        the parameters' what makes a mono-adaptive Solution's ``ode`` and ``stats``."""
        params, kept = self._params, self._kept
        compiled, atol = kept.compiled, kept.atol
        self._solved = _Solved(work)
        if work.params is not self._values:
            values = tuple(work.params.values())
            compiled.p[:len(values)] = values
            signs = _signs(values)
            if signs != self._signs:
                self._signs, self._u0 = signs, None
            if self._bounded_steps:
                bound = _largest_step(work, False, atol)
                kept.options["kmax"] = bound
                self._step_bound = bound if bound < work.T - work.t0 else None
            # (each mark of values taken comes after what they set: a call stopped between,
            # by an error or a KeyboardInterrupt, leaves them to be taken again)
            self._values = work.params
        # a mono-adaptive Solution's makers of these values (but its stats' own values)
        solved, m = self._solved, self._method
        self._makers = {"ode": solved.declaration, "declared": solved,
                        "rhs": partial(solved.dense_rhs, m), "parameters": params}
        self._stats = partial(_prepared_stats, solved, m, params, kept.structure,
                              compiled.compile_time, self._step_bound)
        if work.u0 is not self._u0:
            floor_key = (self._signs, _has_negative(work.u0))  # all the floor depends on
            if floor_key != self._floor_key:
                kept.floor[:] = _floor(work, atol)
                self._bounded = bool(np.isfinite(kept.floor).any())
                self._floor_key = floor_key
            self._initial[:] = work.u0
            if params["tolerance"] < MIN_TOLERANCE and not params["fixed_time_step"]:
                _check_resolvable_tolerance(work, atol, params["tolerance"])
            # (what depends on u0 alone: read again only when it changes)
            self._small = [] if params["fixed_time_step"] else below_tolerance(work.u0, atol)
            self._below = (not params["fixed_time_step"] and params["absolute_tolerance"] is None
                           and starts_below_tolerance(work.u0, atol))
            self._u0 = work.u0
        if self._small:  # (warn_growth_below_tolerance: its rates read the parameters)
            warn_growth(work, compiled, atol, self._small)

    def _go_on(self, work, status, started):
        """The Solution of a prepared run that stopped with ``status`` (the buffers full,
        maximum_steps passed, a failure): it goes on into new buffers, as dn.solve's would
        (:func:`run_started`: the same chunks, the same Solution or error)."""
        self._continued += 1
        params, m, multi_adaptive = self._params, self._method, self._multi_adaptive
        k = self._kept
        advance, arguments = self._loop
        sol = run_started(work, k.compiled, None, multi_adaptive, m, params,
                          (k.loop_atol, k.floor, k.x, k.f0, k.steps, k.options, k.state,
                           k.counters), started,
                          (advance, arguments[:-len(self._buffers)], (status, self._buffers)))
        sol.parameters = dict(params)
        note_step_bound(sol.stats, self._step_bound, work.T - work.t0)
        check_error_at_T(work, k.compiled, None, multi_adaptive, m, params, sol)
        warn_lost_components(work, k.compiled, params, sol)
        if self._below:
            warn_below_tolerance_throughout(work, k.atol, sol)
        return sol


def _prepared_stats(solved, m, params, structure, compile_time, bound, counts, k_next,
                    seconds):
    """The stats of a mono-adaptive prepared call of ``solved`` (:class:`_Solved`) by ``m``
    (made when first read): from its ``counts``, the next step ``k_next`` and its
    ``seconds``."""
    return note_step_bound(_completed_stats(
        _mono_stats(solved.N, structure, counts, k_next), counts, False, m, params,
        compile_time, seconds), bound, solved.T - solved.t0)


#: What a Solver keeps per interval for its prepared calls (:meth:`Solver._workspace`).
_Kept = namedtuple("_Kept", "compiled atol given x f0 steps state counters floor frozen "
                            "structure options loop_atol")


class _Solved:
    """The declaration as a prepared call solved it: what evaluating its Solution reads
    (t0, T, N, u0) at once, the declaration itself (the solver's copy with the call's
    values) made when read, as a loop of small solves seldom does."""

    __slots__ = ("N", "T", "_params", "_rhs", "_work", "t0", "u0")

    def __init__(self, work):
        fields = work.__dict__  # (the call's values: made again when they change)
        self.t0, self.T, self.u0, self._params = (fields["t0"], fields["T"], fields["u0"],
                                                  fields["params"])
        self.N, self._work, self._rhs = work.N, work, None

    def dense_rhs(self, method):
        """The lowered declaration the dense values of ``method`` read
        (:func:`~dolfinode.solution.dense_rhs`), made once for every solution of this
        declaration: made by each, its declaration, lowering and jump test cost 10-18 us of
        a 100-180 us small stiff solve (HIRES, ROBER, POLLU at 6 digits)."""
        if self._rhs is None:
            self._rhs = (dense_rhs(method, self.declaration()),)
        return self._rhs[0]

    def declaration(self):
        """A new copy of the declaration as solved (its own parameter values)."""
        ode = self._work._snapshot()  # (with a later call's values: replaced here)
        ode.__dict__.update(params=Parameters(self._params.items()), u0=self.u0, t0=self.t0,
                            T=self.T)
        return ode
