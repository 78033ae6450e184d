"""Automatic modeling: resolve, average, reduce, check at control points, rebuild.

The pipeline (Jansson, Johnson & Logg 2005, sections 3-7, made automatic and checked):

1. resolve the full model on [t0, t0 + 2 tau]; average it around t_c = t0 + tau;
2. inactivate the fast components (omega_i tau >= 2 pi, omega_i^2 = |(J^2)_ii|) whose average
   does not move (drift < average_tolerance), and
   build the reduced model f~ = f + g~ with g~ = g-bar;
3. solve the reduced model from u-bar(t_c); its solution is the output on (t_c, T] (the
   resolved full solution on [t0, t_c]): the model is built once [t0, t0 + 2 tau] is
   resolved, as in the paper, but the reduced solution starts at the window's centre;
4. at ``control_points`` equispaced times t_k, restart the full model at t_k - tau from the
   reduced state plus the fast fluctuation measured when the model was built (a
   perturbation of the size of the fast oscillation), average it around t_k, record the
   defect g~ - g-bar, and rebuild the model when it exceeds model_tolerance * max |g-bar|
   (with ``subgrid_model="auto"`` the rebuilt model is affine in the slow state, see
   :mod:`dolfinode.modeling.reduced`).

Windows are resolved with a cG method (cG(q) for dG(q), mcG(q) for mdG(q)), see
``_conservative``.
"""
import itertools
import math
import time

import numpy as np

from dolfinode.compile import lower
from dolfinode.methods import parse_method
from dolfinode.modeling.averaging import average_window, window_times
from dolfinode.modeling.declaration import WindowModel
from dolfinode.modeling.reduced import (
    AVERAGE_PERIODS,
    ControlPoint,
    ReducedModel,
    component_frequencies,
    fast_time_scale,
)
from dolfinode.solution import Solution, join_elements

#: Solver parameters that configure the modeling, not the inner solves.
MODELING_PARAMETERS = ("automatic_modeling", "average_length", "average_samples",
                       "average_tolerance", "control_points", "model_tolerance",
                       "rebuild_model", "subgrid_model")
#: Bytes of elements a piece of a resolved window may hold (estimated before solving it).
WINDOW_PIECE_BYTES = 2**26
#: Counters summed over every inner solve.
_SUMMED = ("time slabs", "elements", "rejected steps", "f evaluations", "jacobian evaluations",
           "nonlinear iterations", "failed nonlinear solves", "compile time")


def solve_with_modeling(ode, method, params, solve):
    """Solve ``ode`` with automatic modeling; ``solve`` is the plain driver.

    Returns a :class:`~dolfinode.solution.Solution` whose ``model`` attribute is the
    :class:`~dolfinode.modeling.reduced.ReducedModel`.
    """
    start = time.perf_counter()
    inner = {k: v for k, v in params.items() if k not in MODELING_PARAMETERS}
    inner["number_of_samples"] = 2
    compiled = lower(ode)
    span = ode.T - ode.t0
    tau = params["average_length"]
    fastest = fast_time_scale(compiled, ode.u0, ode.t0)
    # the resolved windows must not step over the fast oscillation (an implicit solver
    # damps it, the indicator may alias it): at least 8 pi = 25 steps per period
    window_step = min(fastest / 4, params["maximum_time_step"] or np.inf)
    if tau is None:
        tau = AVERAGE_PERIODS * fastest
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
    model = ReducedModel(ode, tau, subgrid_model=params["subgrid_model"])
    runs = []

    def run(declaration, method=method, **extra):
        sol = solve(declaration, method, **dict(inner, **extra))
        runs.append(sol.stats)
        return sol

    window_model = WindowModel(ode)
    # dG(q) damps the resolved oscillation a little in every window; the control points
    # restart from the fluctuation of the last build, so with dG the losses would compound
    # over rebuilds (mdG(1) on the simple model: g~ 0.25 -> 0.10 in ten checks). Windows
    # are resolved with cG(q) (mcG(q)), which conserves the oscillation's energy; the output
    # on [t0, t_c] is the first half-window solved again with the method of the reduced
    # solution, so that the returned Solution has one method.
    window_method = _conservative(method)

    # a window of a large system is solved in pieces of about WINDOW_PIECE_BYTES of elements
    # (estimated from the window step), each read at the averaging times and dropped
    q = parse_method(window_method)[1].q
    slab_bytes = 8 * (q + 1) * ode.N
    pieces_per_half = max(1, math.ceil(slab_bytes * tau / window_step / WINDOW_PIECE_BYTES))

    def resolve(u, center, keep_first=False):
        """Solve the full model on [center - tau, center + tau] (in the window's local time,
        see WindowModel) and average it.

        It is solved as two halves that meet at the centre, so that the first half is the
        output before the reduced solution takes over there (then kept whole). Each half is
        solved in ``pieces_per_half`` consecutive pieces, each restarted from the end of
        the last, read at the averaging times and dropped: a window's elements (N per slab,
        thousands of slabs) are most of the memory of a large system. Returns the first
        half (in local time; None unless ``keep_first``), the number of elements of the
        window and its averages, recorded as data of the subgrid model."""
        local = window_model.declaration(u, 0.0, 2 * tau, center - tau)
        window = _SampledWindow(local, np.unique(np.concatenate(
            window_times(tau, tau, params["average_samples"], 0.0, 2 * tau))))
        step = {"maximum_time_step": min(window_step, tau), "method": window_method}
        first = None
        elements = 0
        for half in (0, 1):
            n = 1 if keep_first and half == 0 else pieces_per_half
            ends = tau * (half + np.arange(n + 1) / n)
            for a, b in itertools.pairwise(ends):
                piece = run(window_model.declaration(u, a, b, center - tau), **step)
                window.record(piece)
                elements += piece.stats["elements"]
                u = piece(b)
                step["initial_time_step"] = _last_step(piece)
                if keep_first and half == 0:
                    first = piece
                del piece
        averages = average_window(window, lower(local), tau, tau, params["average_samples"])
        averages.center = center
        model.record(averages)
        return first, elements, averages

    first, _, averages = resolve(ode.u0, ode.t0 + tau, keep_first=window_method == method)
    if window_method != method:
        first = run(window_model.declaration(ode.u0, 0.0, tau, ode.t0),
                    maximum_time_step=min(window_step, tau))
    # inactivated: the fast components (at least one period 2 pi / omega_i in the averaging
    # length tau) whose average does not move; a slow component whose average happens to be
    # constant over the window (a mass at rest by symmetry) stays active
    fast = component_frequencies(compiled, ode.u0, ode.t0) * tau >= 2 * np.pi
    model.build(averages, fast & (averages.drift < params["average_tolerance"]),
                averages.center, compiled)
    fluctuation = averages.fluctuation
    first.t_start = first.t_start + ode.t0  # from the window's local time
    if first.multi:
        first._t_end = first._t_end + ode.t0
    pieces = [first]
    # the reduced solution starts at t_c = t0 + tau from u-bar(t_c): the output is the full
    # solution on [t0, t_c] and the reduced one on (t_c, T] (left-continuous, as for dG)
    step = {}
    u, t_now = averages.u_bar, averages.center
    reduced_start = (u, t_now)
    checks = [ode.t0 + 2 * tau + k * spacing for k in range(1, n_control + 1)]
    for t_next in [ode.t0 + 2 * tau] + checks + [ode.T]:
        segment = run(model.declaration(u, t_now, t_next), **step)
        pieces.append(segment)
        u, t_now = segment(t_next), t_next
        step = {"initial_time_step": _last_step(segment)}
        if t_now >= ode.T or t_now == ode.t0 + 2 * tau:
            continue
        # control point at t_now: full model from t_now - tau, perturbed by the fast fluctuation
        u_start = model.state(segment(t_now - tau)) + np.where(model.active, 0.0, fluctuation)
        elements, averages = resolve(u_start, t_now)[1:]
        defect = model.defect(compiled, averages)
        scale = np.max(np.abs(np.where(model.active, averages.g_bar, 0.0)))
        relative = np.max(np.abs(defect)) / scale if scale > 0 else np.inf
        rebuild = params["rebuild_model"] and relative > params["model_tolerance"]
        if rebuild:
            # g~ is refitted; the inactive set stays that of the first build, so that the
            # reduced problem (and its dual) is one ODE on (t_c, T]
            model.build(averages, ~model.active, t_now, compiled)
            u = np.where(model.active, u, averages.u_bar)
            # chained only through rebuilds, so that the energy errors of the resolved
            # windows do not accumulate over the checks of one model
            fluctuation = averages.fluctuation
        model.control_points.append(ControlPoint(t_now, float(np.linalg.norm(defect)),
                                                 float(relative), bool(rebuild),
                                                 int(elements)))
    model.reduced = _concatenate(model.declaration(*reduced_start, ode.T), pieces[1:], 2)
    sol = _concatenate(ode, pieces, params["number_of_samples"])
    sol.stats = _total_stats(runs, model, time.perf_counter() - start)
    sol.model = model
    return sol


class _SampledWindow:
    """A resolved window known only at the times :func:`average_window` reads (sorted
    ``times``), filled piece by piece with :meth:`record`."""

    def __init__(self, ode, times):
        self.ode = ode
        self.times = times
        self.values = np.empty((ode.N, times.size))

    def record(self, piece):
        """Read a piece of the window (a Solution on a sub-interval) at its times."""
        inside = (self.times >= piece.ode.t0) & (self.times <= piece.ode.T)
        self.values[:, inside] = piece(self.times[inside])

    def __call__(self, times):
        return self.values[:, np.searchsorted(self.times, times)]


def _conservative(method):
    """cG(max(q, 1)) for dG(q), mcG(max(q, 1)) for mdG(q); a cG method itself."""
    multi, m = parse_method(method)
    return method if m.family == "cG" else f"{'m' if multi else ''}cG({max(m.q, 1)})"


def _last_step(sol):
    """The last step of a solution (of component 0 for a multi-adaptive one)."""
    return float(sol.time_steps(0)[1][-1] if sol.multi else sol.k[-1])


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
        return Solution.multi_adaptive(ode, method, *arrays, {}, number_of_samples)
    chunks = [[p.t_start, p.k, p.values] for p in pieces]
    pieces.clear()
    return Solution(ode, method, *join_elements(chunks), {}, number_of_samples)


def _total_stats(runs, model, wall):
    stats = {name: sum(r[name] for r in runs) for name in _SUMMED}
    stats.update({"method": runs[0]["method"], "solve time": wall,
                  "newton": any(r["newton"] for r in runs),
                  "inner solves": len(runs),
                  "average length": model.average_length,
                  "model builds": len(model.built),
                  "largest model defect": model.largest_defect})
    return stats
