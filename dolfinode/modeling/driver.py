"""Automatic modeling: resolve, average, reduce, check at control points, rebuild.

The pipeline (Jansson, Johnson & Logg 2005, sections 3-7, made automatic and checked):

1. resolve the full model on [t0, t0 + 2 tau]; average it around t_c = t0 + tau;
2. inactivate the fast components (omega_i tau >= 2 pi, omega_i^2 = J_ii^2 + the oscillatory
   couplings) whose average does not move (drift < average_tolerance), and the relaxing ones
   (put on their slow manifold, see :mod:`dolfinode.modeling.manifold`), and build the
   reduced model f~ = f + g~ with g~ = g-bar (affine in the slow state from the start for
   ``subgrid_model="auto"`` when the half windows show g-bar moving);
3. solve the reduced model from u-bar(t_c); its solution is the output on (t_c, T] (the
   resolved full solution on [t0, t_c]): the model is built once [t0, t0 + 2 tau] is
   resolved, as in the paper, but the reduced solution starts at the window's centre;
4. at ``control_points`` equispaced times t_k, restart the full model at t_k - tau from the
   reduced state plus the fast fluctuation measured when the model was built, carried to the
   current slow state by its action (:func:`~dolfinode.modeling.reduced.adiabatic_scaling`),
   average it around t_k, record the defect g~ - g-bar, and rebuild the model when it
   exceeds model_tolerance (max |g-bar| + tolerance) (with ``subgrid_model="auto"`` the
   rebuilt model is affine in the slow state, see :mod:`dolfinode.modeling.reduced`);
5. check the result a posteriori (:mod:`dolfinode.modeling.validity`): a ModelingWarning,
   or with ``strict=True`` a SolverError, when the error estimate exceeds the tolerance.

Windows are resolved with cG(max(q, 4)) (mcG for multi-adaptive methods), see
:func:`~dolfinode.modeling.flow.resolving_method`.
"""
import functools
import math
import time
import warnings

import numpy as np

from dolfinode.compile import lower
from dolfinode.errors import SolverError
from dolfinode.io.history import check_sample_times
from dolfinode.methods import parse_method
from dolfinode.modeling.averaging import WindowAverager
from dolfinode.modeling.declaration import WindowModel
from dolfinode.modeling.flow import (
    FLOW_START,
    frequency_change,
    resolving_method,
    solve_flow,
    stiffness_parameter,
)
from dolfinode.modeling.reduced import (
    ControlPoint,
    ReducedModel,
    adiabatic_scaling,
    default_average_length,
    fast_time_scale,
    inactive_components,
)
from dolfinode.modeling.validity import check_oscillation, check_validity, model_fails
from dolfinode.solution import Solution, equispaced, join_elements

#: Solver parameters that configure the modeling, not the inner solves.
MODELING_PARAMETERS = ("automatic_modeling", "average_length", "average_samples",
                       "average_tolerance", "control_points", "model_tolerance",
                       "rebuild_model", "subgrid_model", "strict")
#: Bytes of elements a piece of a resolved window should hold (its length is set from the
#: last piece's step density; the first from the window step).
WINDOW_PIECE_BYTES = 2**26
#: Bytes of elements of the resolved start [t0, t_c] the returned Solution may hold
#: (estimated); a larger start is not stored but solved again where it is evaluated, see
#: :class:`ModelingSolution`.
START_BYTES = 2**26
#: Above this fraction of [t0, T] resolved in the windows (the start's and one per control
#: point, 2 tau each) a solve with automatic modeling warns that modeling saves little: the
#: windows then cost about what a full solve would, and the averaging comes on top.
RESOLVED_WARNING = 0.5
#: Counters summed over every inner solve.
_SUMMED = ("time slabs", "elements", "rejected steps", "f evaluations", "jacobian evaluations",
           "nonlinear iterations", "failed nonlinear solves", "compile time")


def solve_with_modeling(ode, method, params, solve):
    """Solve ``ode`` with automatic modeling; ``solve`` is the plain driver.

    Returns a :class:`~dolfinode.solution.Solution` whose ``model`` attribute is the
    :class:`~dolfinode.modeling.reduced.ReducedModel`: a :class:`ModelingSolution` when the
    resolved start [t0, t_c] would exceed START_BYTES.
    """
    start_time = time.perf_counter()
    # the declaration as solved: the model, the Solution and a start solved again when
    # evaluated read it, which later changes of the user's values (u0, params) must not reach
    ode = ode._snapshot()
    inner = {k: v for k, v in params.items() if k not in MODELING_PARAMETERS}
    # the output's samples are the user's; the inner solves (windows, pieces in their local
    # time, reduced segments) keep two
    inner.update(number_of_samples=2, sample_times=None)
    samples = _samples(ode, params)
    # the a posteriori check bounds the discretisation error by the tolerance: keep the step
    # estimate below it rather than aim the error at it
    inner["calibrate_tolerance"] = False
    inner["estimate_global_error"] = False  # (the pieces' ends are not the solution's T)
    compiled = lower(ode)
    span = ode.T - ode.t0
    runs = []

    def solve_piece(declaration, method=method, **extra):
        return solve(declaration, method, **dict(inner, **extra))

    def run(declaration, method=method, **extra):
        sol = solve_piece(declaration, method, **extra)
        runs.append(sol.stats)
        return sol

    def solve_flow_model(reason):
        return solve_flow(ode, method, params["tolerance"], params["average_samples"],
                          samples, run, reason)

    def flow(reason):
        """The flow-averaged model instead (:mod:`dolfinode.modeling.flow`), checked."""
        sol = solve_flow_model(reason)
        return _checked(sol, sol.model, runs, params, start_time, stacklevel=6)

    if params["subgrid_model"] == "flow":
        return flow("subgrid_model='flow'")
    tau = params["average_length"]
    fastest = fast_time_scale(compiled, ode.u0, ode.t0)
    # the resolved windows must not step over the fast oscillation (an implicit solver
    # damps it, the indicator may alias it): at least 8 pi = 25 steps per period
    window_step = min(fastest / 4, params["maximum_time_step"] or np.inf)
    if tau is None:
        tau = default_average_length(compiled, ode.u0, ode.t0)
        if not 4 * tau < span:
            raise ValueError(f"automatic modeling found no fast time scale in [t0, T]: the "
                             f"fastest one, {fastest:.3g}, gives average_length "
                             f"{tau:.3g}, too long for T - t0 = {span:.3g}; give "
                             "average_length, or solve without automatic_modeling")
    n_control = params["control_points"]
    spacing = (span - 2 * tau) / (n_control + 1)
    if not spacing > 2 * tau:
        raise ValueError(f"average_length = {tau:.3g} with {n_control} control points does not "
                         f"fit in [{ode.t0}, {ode.T}]: every control point needs 2 tau; use "
                         "fewer control_points or a shorter average_length")
    resolved = (n_control + 1) * 2 * tau / span
    if resolved > RESOLVED_WARNING:
        warnings.warn(f"automatic modeling resolves the full model on {resolved:.0%} of "
                      f"[t0, T] ({n_control + 1} windows of 2 x average_length = {2 * tau:.3g}): "
                      f"it saves at most {1 - resolved:.0%} of a full solve and adds the "
                      "averaging; solving without automatic_modeling is likely faster (or use "
                      "fewer control_points or a shorter average_length)", stacklevel=3)
    model = ReducedModel(ode, tau, subgrid_model=params["subgrid_model"], spacing=spacing,
                         tolerance=params["tolerance"],
                         model_tolerance=params["model_tolerance"])
    window_model = WindowModel(ode)
    # dG(q) damps the resolved oscillation a little in every window; the control points
    # restart from the fluctuation of the last build, so with dG the losses would compound
    # over rebuilds (mdG(1) on the simple model: g~ 0.25 -> 0.10 in ten checks). Windows
    # are resolved with cG (mcG), which conserves the oscillation's energy, of degree 4 at
    # least (fewer steps per fast period); the output on [t0, t_c] is the first half-window
    # solved again with the method of the reduced solution, so that the returned Solution
    # has one method.
    window_method = resolving_method(method)
    window_options = {"maximum_time_step": min(window_step, tau)}

    # a window of a large system is solved in pieces of about WINDOW_PIECE_BYTES of elements
    # (the first estimated from the window step), each read at the averaging times and
    # dropped
    q = parse_method(window_method)[1].q
    half_bytes = 8 * (q + 1) * ode.N * tau / window_step
    first_length = 2 * tau / max(1, math.ceil(2 * half_bytes / WINDOW_PIECE_BYTES))
    pace = {"length": first_length}  # windows after the first start at the last density

    def resolve(u, center, record_first=None):
        """Solve the full model on [center - tau, center + tau] (in the window's local time
        [0, 2 tau], see WindowModel) and average it.

        The window is solved in consecutive pieces (see _pieces), each restarted from the
        end of the last, read at the averaging times and dropped: a window's elements (N
        per slab, thousands of slabs) are most of the memory of a large system.
        ``record_first`` is given the pieces of the first half (the output on [t0, t_c] for
        the first window). Returns the number of elements of the window and its averages,
        recorded as data of the subgrid model."""
        local = window_model.declaration(u, 0.0, 2 * tau, center - tau)
        averager = WindowAverager(lower(local), tau, tau, params["average_samples"], 0.0,
                                  2 * tau)
        elements = 0
        # (a window that gives no output is not cut at its centre: one inner solve fewer)
        stops = (0.0, 2 * tau) if record_first is None else (0.0, tau, 2 * tau)
        try:
            for piece in _pieces(run, window_model, u, stops, center - tau,
                                 dict(window_options, method=window_method), pace):
                averager.record(piece)
                elements += piece.stats["elements"]
                if record_first is not None and piece.ode.T <= tau:
                    record_first(piece)
                del piece
        except SolverError as error:
            raise _window_failure(error, center, tau, ode.t0) from error
        averages = averager.averages()
        averages.center = center  # from the window's local time
        for half in averages.halves:
            half.center += center - tau
        model.record(averages)
        return elements, averages

    # the output on [t0, t_c]: kept element by element when small, else only read at the
    # output samples while it is solved (and solved again where it is evaluated)
    keep_start = half_bytes <= START_BYTES
    if keep_start:
        kept = []
        record_start = kept.append
    else:
        # solved again as in the solve: the first half of the first window, or its own
        # (module-level pieces: a ModelingSolution pickles)
        start = _Start(functools.partial(_start_pieces, solve, inner, window_model, ode, tau,
                                         dict(window_options, method=method), first_length),
                       tau, ode.t0, ode.N, samples if isinstance(samples, np.ndarray)
                       else equispaced(ode.t0, ode.T, samples))
        record_start = start.record
    _, averages = resolve(ode.u0, ode.t0 + tau,
                          record_first=record_start if window_method == method else None)
    if window_method != method:
        for piece in _pieces(run, window_model, ode.u0, (0.0, tau), ode.t0,
                             dict(window_options, method=method), {"length": first_length}):
            record_start(piece)
            del piece
    # inactivated: the fast components whose average does not move, with their fast
    # partners; a slow component whose average happens to be constant over the window (a
    # mass at rest by symmetry) stays active
    auto = params["subgrid_model"] == "auto"
    first_jacobian = compiled.jacobian_matrix(averages.u_bar, averages.center)
    halves = [compiled.jacobian_matrix(h.u_bar, h.center) for h in averages.halves] \
        if auto else [first_jacobian] * 2
    if frequency_change(*halves, tau) * span / (tau / 2) > FLOW_START \
            and stiffness_parameter(ode, compiled):
        return flow("subgrid_model='auto': the first window shows a fast frequency moving "
                    "with the slow state")
    try:
        inactive = inactive_components(ode, compiled, tau, averages.drift,
                                       params["average_tolerance"])
    except ValueError:
        # with an average_length of the user's the error may be theirs (too short): say so
        if not (auto and params["average_length"] is None
                and stiffness_parameter(ode, compiled)):
            raise
        return flow("subgrid_model='auto': no component can be inactivated (the slow "
                    "variables are combinations of fast components)")
    model.build(averages, inactive, averages.center, compiled)
    fluctuation = averages.fluctuation
    fluctuation_jacobian = _end_jacobian(compiled, model, averages, tau)
    segments = []
    # the reduced solution starts at t_c = t0 + tau from u-bar(t_c): the output is the full
    # solution on [t0, t_c] and the reduced one on (t_c, T] (left-continuous, as for dG).
    # It is solved in one piece to T while the checks keep the model, and from a rebuild
    # to the next check (a rebuilt model is likely rebuilt again): the part of a piece
    # beyond a rebuild is dropped, and the part before it solved again up to the check
    checks = [ode.t0 + 2 * tau + k * spacing for k in range(1, n_control + 1)]
    # (the constant model until then: solved to that check only, it is rebuilt there)
    early = model.early_check is not None \
        and averages.center + model.early_check < (checks[0] if checks else ode.T - tau)
    if early:
        checks.insert(0, averages.center + model.early_check)
    start_state = (averages.u_bar, averages.center, {})  # u, t and step of the piece

    def reduced(end):
        u, t_from, step = start_state
        return run(model.declaration(u, t_from, end), **step)

    reduced_start = start_state[:2]
    segment = reduced(checks[0] if early else ode.T)
    for k, t_now in enumerate(checks):
        # control point at t_now: full model from t_now - tau, perturbed by the fast
        # fluctuation of the last build carried to the current slow state (its action kept)
        u_slow = model.state(segment(t_now - tau))
        scaling = adiabatic_scaling(fluctuation_jacobian,
                                    compiled.jacobian_matrix(u_slow, t_now - tau))
        u_start = u_slow + np.where(model.active, 0.0, scaling * fluctuation)
        elements, averages = resolve(u_start, t_now)
        change = frequency_change(first_jacobian, compiled.jacobian_matrix(
            averages.u_bar, t_now), tau) if auto else 0.0
        if change > FLOW_START and stiffness_parameter(ode, compiled):
            return flow(f"subgrid_model='auto': at the control point t = {t_now:.4g} a fast "
                        f"frequency has moved by {change:.0%} with the slow state")
        defect = model.defect(compiled, averages)
        # + tolerance: g-bar vanishes where the fast components sit on their average
        # (1e-19 on Michaelis-Menten), and the defect is then not relative to anything
        g_bar = np.where(model.active, averages.g_bar, 0.0)
        relative = np.max(np.abs(defect)) / (np.max(np.abs(g_bar)) + params["tolerance"])
        rebuild = params["rebuild_model"] and relative > params["model_tolerance"]
        model.control_points.append(ControlPoint(t_now, float(np.linalg.norm(defect)),
                                                 float(relative), bool(rebuild),
                                                 int(elements), defect, g_bar))
        if not rebuild and segment.ode.T > t_now:
            continue
        if segment.ode.T > t_now:  # the old model up to the check only
            segment = reduced(t_now)
        segments.append(segment)
        u = segment(t_now)
        if rebuild:
            # g~ is refitted; the inactive set stays that of the first build, so that the
            # reduced problem (and its dual) is one ODE on (t_c, T]
            model.build(averages, ~model.active, t_now, compiled)
            u = np.where(model.active, u, averages.u_bar)
            # chained only through rebuilds, so that the energy errors of the resolved
            # windows do not accumulate over the checks of one model
            fluctuation = averages.fluctuation
            fluctuation_jacobian = _end_jacobian(compiled, model, averages, tau)
        start_state = (u, t_now, {"initial_time_step": _last_step(segment)})
        segment = reduced(checks[k + 1] if rebuild and k + 1 < len(checks) else ode.T)
    segments.append(segment)
    del segment
    model.reduced = _concatenate(model.declaration(*reduced_start, ode.T), segments, 2)
    if keep_start:
        for piece in kept:  # from the window's local time
            piece.t_start = piece.t_start + ode.t0
            if piece.multi:
                piece._t_end = piece._t_end + ode.t0
        kept.append(model.reduced)
        sol = _concatenate(ode, kept, samples)
        # the reduced model starts from its own state: dG(q)'s dense value reads it there
        # (solution._evaluate_dg), as the solution that solves the start again does
        sol._restarts = ([ode.t0, model.reduced.ode.t0], [ode.u0, model.reduced.ode.u0])
    else:
        sol = ModelingSolution(ode, model, start, samples)
    estimate = model.modeling_error() if model.control_points else None
    if auto and model_fails(estimate, params["tolerance"]) and stiffness_parameter(ode, compiled):
        # the model failed its check: the flow carries the fast state that the reduced model
        # froze (a damped or relaxing fast amplitude); the one of smaller estimate is returned
        flowed, flow_estimate = _flow_instead(solve_flow_model, estimate)
        if flowed is not None:
            return _checked(flowed, flowed.model, runs, params, start_time,
                            estimate=flow_estimate)
    sol = _checked(sol, model, runs, params, start_time, estimate=estimate)
    sol.stats["resolved fraction"] = resolved
    return sol


def _flow_instead(solve_flow_model, estimate):
    """(the flow-averaged solution, its estimate) where that is below the failed
    ``estimate`` of the reduced model, else (None, None): also where the flows' averages do
    not fit in [t0, T]."""
    try:
        sol = solve_flow_model(f"subgrid_model='auto': the reduced model failed its check "
                               f"(estimate {estimate.total:.3g}, local {estimate.local:.3g})")
    except ValueError:
        return None, None
    flow_estimate = sol.model.modeling_error()
    if max(flow_estimate.total, flow_estimate.local) < max(estimate.total, estimate.local):
        return sol, flow_estimate
    return None, None


def _samples(ode, params):
    """The output samples: ``sample_times`` (checked in [t0, T]), else the number of
    equispaced ones."""
    times = params["sample_times"]
    check_sample_times(ode, times)
    return params["number_of_samples"] if times is None else times


def _checked(sol, model, runs, params, start_time, stacklevel=5, estimate=None):
    """``sol`` with its model, stats and the a posteriori check of the model (its warning
    ``stacklevel`` frames up from check_validity: the caller of dn.solve; ``estimate`` the
    model's, where made already)."""
    sol.stats = _total_stats(runs, model, time.perf_counter() - start_time)
    sol.model = model
    model.estimate = check_validity(model, params["tolerance"], params["model_tolerance"],
                                    params["strict"], stacklevel, estimate)
    sol.stats["modeling error estimate"] = model.estimate.total if model.estimate else np.nan
    sol.stats["fast oscillation"] = check_oscillation(model, params["tolerance"], stacklevel)
    return sol


class ModelingSolution(Solution):
    """The output of automatic modeling whose resolved start [t0, t_c] is not stored (its
    elements would exceed START_BYTES): the full model's Galerkin solution on [t0, t_c],
    then the reduced solution ``model.reduced`` on (t_c, T].

    The output samples ``t, y`` were read while the start was solved; at other times in
    (t0, t_c] the start is solved again, deterministically and piece by piece, from t0 up
    to the latest of them (at most the cost of a half-window). Its elements are not stored:
    ``t_start``, ``k``, ``values``, :meth:`time_steps` and :meth:`elements` raise
    AttributeError (``model.reduced`` has the reduced solution's).
    """

    def __init__(self, ode, model, start, number_of_samples):
        self.ode, self.model, self.stats = ode, model, {}
        self.method = model.reduced.method
        self._start = start
        self._sample(number_of_samples)

    @property
    def multi(self):
        return self.model.reduced.multi

    def _evaluate(self, times):
        reduced = self.model.reduced
        out = np.empty((self.ode.N, times.size))
        late = times > reduced.ode.t0
        out[:, late] = reduced(times[late])
        out[:, ~late] = self._start(times[~late])
        return out

    def _not_stored(self, *args, **kwargs):
        raise AttributeError(
            f"the elements of the resolved start [{self.ode.t0}, {self.model.reduced.ode.t0}] "
            "of this automatic-modeling solution are not stored (they would exceed "
            "dolfinode.modeling.driver.START_BYTES; sol(t) solves it again); "
            "sol.model.reduced has the reduced solution's elements")

    t_start = k = values = property(_not_stored)
    time_steps = elements = _not_stored

    def __repr__(self):
        kind = "multi-adaptive" if self.multi else "mono-adaptive"
        return (f"ModelingSolution({self.method.name}, {kind}, N={self.ode.N}, "
                f"t=[{self.ode.t0}, {self.ode.T}], start not stored)")


class _Start:
    """The full model's solution on [t0, t_c], the first half-window, without its elements:
    read at the output samples while it is solved (:meth:`record`), and solved again where
    it is evaluated at other times.

    ``pieces()`` solves it again and yields its pieces, as in the solve (on [0, tau], the
    local time of the first window, which starts at t0)."""

    def __init__(self, pieces, tau, t0, N, sample_times):
        self.pieces, self.tau, self.t0, self.N = pieces, tau, t0, N
        self.samples = _SampledWindow(N, np.unique(self._local(
            sample_times[sample_times <= t0 + tau])))

    def _local(self, times):
        return np.minimum(times - self.t0, self.tau)

    def record(self, piece):
        self.samples.record(piece)

    def __call__(self, times):
        local = self._local(times)
        window = self.samples
        if not np.isin(local[local > 0], window.times).all():
            window = _SampledWindow(self.N, np.unique(local))
            for piece in self.pieces():  # up to the latest time
                window.record(piece)
                done = piece.ode.T >= window.times[-1]
                del piece
                if done:
                    break
        return window(local)


class _SampledWindow:
    """A solution known only at sorted ``times``, filled piece by piece with
    :meth:`record`."""

    def __init__(self, N, times):
        self.times = times
        self.values = np.empty((N, times.size))

    def record(self, piece):
        """Read a piece of the window (a Solution on a sub-interval) at its times (U, as
        :func:`_concatenate`'s solution of the pieces kept reads them)."""
        inside = (self.times >= piece.ode.t0) & (self.times <= piece.ode.T)
        self.values[:, inside] = piece._galerkin(self.times[inside])

    def __call__(self, times):
        return self.values[:, np.searchsorted(self.times, times)]


def _start_pieces(solve, inner, window_model, ode, tau, step, first_length):
    """The pieces of the resolved start [t0, t_c] of ``ode`` solved again, as in the solve
    (:func:`_pieces` from u0 on [0, tau] of the first window, ``solve`` the plain driver with
    the inner parameters ``inner``)."""
    return _pieces(functools.partial(_solve_inner, solve, inner), window_model, ode.u0,
                   (0.0, tau), ode.t0, step, {"length": first_length})


def _solve_inner(solve, inner, declaration, method, **extra):
    """``solve`` (declaration, method) with the parameters ``inner`` and ``extra``."""
    return solve(declaration, method, **dict(inner, **extra))


def _pieces(solve, window_model, u, stops, shift, step, pace):
    """The full model solved on consecutive pieces of a window from stops[0], ending at
    every stop (in the local time of the window starting at ``shift``), each restarted from
    the end of the last with its last step: yields the solutions, to be read and dropped.

    A piece is at most ``pace["length"]`` long (equal pieces up to the next stop); after
    each, that length is set to hold about WINDOW_PIECE_BYTES of elements at its step
    density (the steps of a window vary: on the lattice the windows of the control points
    take up to 4 times the steps of the first). ``solve(declaration, **step)`` solves one
    piece."""
    step = dict(step)
    a = stops[0]
    for stop in stops[1:]:
        while a < stop:
            n = math.ceil((stop - a) / pace["length"])
            b = a + (stop - a) / n if n > 1 else stop
            piece = solve(window_model.declaration(u, a, b, shift), **step)
            yield piece
            pace["length"] = (b - a) * WINDOW_PIECE_BYTES / piece.values.nbytes
            u, step["initial_time_step"], a = piece(b), _last_step(piece), b
            del piece


def _window_failure(error, center, tau, t0):
    """The SolverError of a resolved window [center - tau, center + tau], whose pieces run
    in the window's local time from 0: its time made global, and the window named (a
    parametric resonance, y'' = -10^6 (1 + x p / 50) y with p rotating at twice y's
    frequency, blew up in a check window at local time 0.0082, which the message gave as
    t = 0.0082 instead of 2.731)."""
    start = center - tau
    when = None if error.t is None else start + error.t
    which = ("the first window" if start == t0 else
             f"the window of the control point at t = {center:.6g}, restarted from the "
             "reduced state and the recorded fluctuation (try fewer control_points, a shorter "
             "average_length, or solve without automatic_modeling)")
    return SolverError(f"automatic modeling: resolving the full model on [{start:.6g}, "
                       f"{center + tau:.6g}], {which}, failed"
                       + ("" if when is None else f" at t = {when:.6g}")
                       + f" (times below count from {start:.6g}): {error}", t=when)


def _end_jacobian(compiled, model, averages, tau):
    """df/du at the slow state where the fluctuation was recorded, the window's end
    t_c + tau (u-bar + fluctuation on the active components, the fast ones at their
    average): the slow state moves over the window."""
    return compiled.jacobian_matrix(model.state(averages.u_bar + averages.fluctuation),
                                    averages.center + tau)


def _last_step(sol):
    """The larger of the last two steps of a solution (of component 0 for a multi-adaptive
    one): the last is cut to end at T, down to 1e-20 on the lattice's window pieces."""
    return float(np.max(sol.time_steps(0)[1][-2:] if sol.multi else sol.k[-2:]))


def _concatenate(ode, pieces, number_of_samples):
    """One Solution on [t0, T] from solutions on consecutive intervals.

    The list ``pieces`` is emptied: a mono-adaptive piece's arrays are released as soon as
    they are copied (unless referenced elsewhere), so that a resolved window of a large
    system is not held twice."""
    method = pieces[0].method
    if pieces[0].multi:
        comp = [np.repeat(np.arange(ode.N), np.diff(p._component_ptr)) for p in pieces]
        arrays = [np.concatenate(comp)] + [np.concatenate([getattr(p, name) for p in pieces])
                                           for name in ("t_start", "_t_end", "values")]
        pieces.clear()
        sol = Solution.multi_adaptive(ode, method, *_resolved(arrays, arrays[2]), {},
                                      number_of_samples)
    else:
        chunks = [[p.t_start, p.k, p.values] for p in pieces]
        pieces.clear()
        arrays = join_elements(chunks)
        sol = Solution(ode, method, *_resolved(arrays, arrays[0] + arrays[1]), {},
                       number_of_samples)
    # (the pieces may solve other models than ode: cG(q)'s and mcG(q)'s dense value is U)
    sol._rhs = None
    return sol


def _resolved(arrays, t_end):
    """The element ``arrays`` (t_start second for multi-adaptive ones, first for mono) without
    the elements that end where they start (``t_end``): steps of a window solved in its
    local time from 0 (the first, 5e-11 on the seed model) that moved to t0 = 1e6 are below
    the spacing of doubles there, and an element of length 0 has no polynomial."""
    t_start = arrays[1] if len(arrays) == 4 else arrays[0]
    kept = t_end > t_start
    return arrays if kept.all() else [array[kept] for array in arrays]


def _total_stats(runs, model, wall):
    stats = {name: sum(r[name] for r in runs) for name in _SUMMED}
    stats.update({"method": runs[0]["method"], "solve time": wall,
                  "newton": any(r["newton"] for r in runs),
                  "inner solves": len(runs),
                  "average length": model.average_length,
                  "model builds": len(model.built),
                  "largest model defect": model.largest_defect})
    return stats
