"""``method="auto"``: the mono- or multi-adaptive variant of a method, switched between as
the problem's scales change.

A multi-adaptive element costs several mono-adaptive component-steps (its own moments,
sweeps and partition): mcG(q)/mdG(q) pay off only where the components' steps spread widely,
and the spread may change during a solve (a fast oscillation excited later, a transient that
dies out). [t0, T] is solved in stretches, the first FIRST_STRETCH (T - t0) long with the
mono-adaptive variant (cheap to start), each next one STRETCH_GROWTH x longer up to
MAX_STRETCH (T - t0), each from the end value of the last with its last step(s). A
mono-adaptive stretch follows this schedule (its restart is a solve's fixed cost); a
multi-adaptive one is at least so long that its restart (its start, all components active
until found at rest, or a solve's fixed cost from the 2nd and 3rd stretches,
:func:`_restart_cost`; the largest measured so far) is RESTART_SHARE of it
(:func:`_shortest_stretch`), at most LONGEST_STRETCH (T - t0), and runs to T when what would
be left after it is shorter than that (:func:`_stretch_end`). After each stretch the
current variant's rate r at its end (CPU time per element x the elements per unit time of
the stretch's second half, :func:`_steady_rate`) is measured and the other's predicted from
the elements it would take over that second half,

    r_other = r x (E_other / E) x (c_other / c),

with c the CPU time per element: E_mono / E of a multi-adaptive stretch from the smallest
component step (the solve's "efficiency index", scaled by the fastest component's share of
elements in the second half, :func:`_mono_elements_late`); E_multi / E of a mono-adaptive
stretch from the spread of its components' local errors in the second half
(:func:`_multi_elements_late`) x MULTI_ELEMENTS; c_multi / c_mono the latest ratio measured
on stretches, COST_RATIO before both were (each prediction records which); r_other is
scaled by measured / predicted of the last trial of the other variant, until that variant
runs a stretch. When r_other < r /
SWITCH_MARGIN, the next stretch (a stretch of the schedule, not the first: a short trial
would be mostly its start) is a trial of the other variant from the current state, a
multi-adaptive one starting each component at its own step (:func:`_component_steps`, not
all at the common one). The trial is kept (no stretch is solved twice) and its variant
continues if its measured rate is below r; a multi-adaptive trial that does not continue
among mono-adaptive stretches only is solved again instead (kept, it would turn every slab
into N elements of the joined solution). The margin on the prediction keeps a problem that
does not change from paying for trials; the trial itself is measured, so a noisy
measurement costs one stretch at most. The stretches and trials with their evidence are in
``sol.stats["family choice"]``; a solution with stretches of both variants is represented
in the multi-adaptive form (a mono-adaptive slab is one element per component: mcG(q) on a
common partition is cG(q)), so evaluation, samples and ``estimate_error`` see one solution;
the mono-adaptive slabs are kept as its shared slabs (a
:class:`~dolfinode.solution.MixedSolution`), copied into every component's elements only
when those are read.

A small system is not cut into stretches: with N < COST_RATIO x MULTI_ELEMENTS x
SWITCH_MARGIN components the multi-adaptive variant cannot be predicted cheaper even with
every component but one at rest (its elements are at least MULTI_ELEMENTS x the fastest
component's, 1/N of the mono-adaptive ones), so the mono-adaptive variant solves [t0, T] in
one call, "decided once" in the evidence.

Decided once (after the first stretch and its trial, the chosen variant solving [t0, T]
from the start): with a goal, events, breakpoints, automatic modeling, a progress bar,
sample times, or a history kept only as samples or in a file.

Limitation: a change of scales is seen at the end of the stretch it happens in (up to 20 %
of [t0, T] later, more where multi-adaptive restarts are dear: up to the rest of [t0, T]),
and the prediction of the multi-adaptive elements and their cost is a prior until a trial
measured them (MULTI_ELEMENTS x COST_RATIO = 14 x the mono-adaptive cost per estimated
element): a variant predicted no cheaper is not measured. Each stretch restarts the variant
(its fixed cost per call, about 0.2 ms; a multi-adaptive one finds its components at rest
again), so on a solve of a few ms the stretches cost 10-40 % (doc/benchmarks/auto.md). A
trial is compared with the rate of the stretch before it, an earlier window: a transient
there that makes the current variant dear can switch to a variant only as cheap later.
"""
import re
import time

import numpy as np
from numba import njit

from dolfinode.compile import lower
from dolfinode.errors import SolverError
from dolfinode.solution import MixedSolution, Solution

#: "auto" is "auto:cG(2)"; "auto:cG(q)" and "auto:dG(q)" switch between cG(q)/mcG(q), dG(q)/mdG(q).
_AUTO_PATTERN = re.compile(r"^\s*auto\s*(?::\s*((?:cG|dG)\(\s*\d+\s*\)))?\s*$", re.IGNORECASE)
DEFAULT_BASE = "cG(2)"
#: The first stretch and the longest, as fractions of T - t0, and the growth of the next ones
#: (1, 4, 16, 20, 20, 20, 19 %: a change is seen within 20 % of [t0, T]; 25 % let the late
#: fast bank of doc/benchmarks/auto.md run cG(2) 0.3 longer over its ramp, at 1.23-1.26x).
FIRST_STRETCH, MAX_STRETCH, STRETCH_GROWTH = 1e-2, 0.2, 4
#: The other variant is tried when predicted SWITCH_MARGIN x cheaper than the current one
#: (the prediction is a heuristic, within 2x on the benchmark problems).
SWITCH_MARGIN = 1.5
#: CPU time per multi-adaptive element / per mono-adaptive one until both were measured: the
#: low end of the problems of doc/benchmarks/auto.md whose steps spread (6.8-20; 3-4 where
#: every slab is synchronised), so that a multi-adaptive variant is rather measured than missed.
COST_RATIO = 7.0
#: Multi-adaptive elements / :func:`_multi_elements_late`' estimate (2-2.5 on the benchmarks).
MULTI_ELEMENTS = 2.0
#: A stretch is at least so long that its restart (:func:`_shortest_stretch`) is at most this
#: share of it: a small problem, whose solve is mostly a solve's fixed cost, or a
#: multi-adaptive one, whose components are all active again at a restart until found at
#: rest, is not cut up for nothing.
RESTART_SHARE = 0.05
#: ... but at most this fraction of T - t0, so that a change of scales is still seen; a
#: multi-adaptive stretch runs to T when what would be left after it is shorter than that
#: least length (the reaction front's restarts after the trial cost 0.6-1 ms of 11 ms).
LONGEST_STRETCH = 0.5
#: A component's first multi-adaptive step after a mono-adaptive stretch is at most this
#: multiple of the common step (a component at rest has no error to size it by).
MAX_STEP_GROWTH = 10.0
#: Parameters a stretch overrides: output, progress, modeling, events and the error at T are
#: the whole solve's business (sample times and a history file refer to [t0, T]).
_STRETCH_PARAMETERS = {"number_of_samples": 2, "sample_times": None, "dense_output": True,
                       "progress": False, "automatic_modeling": False, "events": None,
                       "estimate_global_error": False}
#: The CPU clock the rates are measured with.
_clock = time.process_time


def auto_base(method):
    """The base method name ("cG(q)" or "dG(q)") of an "auto" method name, else None."""
    if not isinstance(method, str):
        return None
    match = _AUTO_PATTERN.match(method)
    if match is None:
        return None
    base = match.group(1) or DEFAULT_BASE
    return base[0].lower() + base[1].upper() + base[2:].replace(" ", "")


def solve_auto(solve, ode, base, goal, parameters, params):
    """``solve(ode, "auto:" + base, goal=goal, **parameters)``: see the module docstring.

    Parameters
    ----------
    solve : the driver, ``solve(ode, method, **parameters)``
    ode : ODE
    base : "cG(q)" or "dG(q)"
    goal : the solve's goal, or None
    parameters, params : the solve's parameters as given and as checked

    Returns
    -------
    Solution
        ``sol.stats["method"]`` names the variants in turn ("cG(2) -> mcG(2)");
        ``sol.stats["family choice"]`` holds "method" (the variant at the end, or the one
        chosen once), "stretches" (per kept stretch: method, interval, CPU time, and the
        rate, the other's predicted rate and the cost ratio it assumed with "measured" or
        "prior" (None after the last), or "trial"), "checks" (per trial of the other
        variant: time, the current, predicted and measured rates, whether it switched, or
        the trial's error) and, when decided once, "decided once".
    """
    lower(ode)  # compiled once, shared by the stretches (a copy would compile again)
    switching = _Switching(solve, ode, base, {**parameters, **_STRETCH_PARAMETERS}, params)
    if not switching.multi_can_pay():
        sol = solve(ode, base, goal=goal, **parameters)
        switching.evidence["decided once"] = (
            f"{ode.N} components: m{base} cannot be predicted {SWITCH_MARGIN}x cheaper even "
            "with all components but one at rest (COST_RATIO x MULTI_ELEMENTS / N = "
            f"{COST_RATIO * MULTI_ELEMENTS / ode.N:.2g})")
    elif _switchable(goal, params):
        sol = switching.run(params["number_of_samples"])
        sol.parameters = params
    else:
        switching.run(params["number_of_samples"], stretches=1)
        sol = solve(ode, switching.current, goal=goal, **parameters)
        switching.evidence["decided once"] = ("a goal, events, breakpoints, modeling, progress, "
                                              "sample times or a history not in memory")
    switching.evidence["method"] = switching.current
    sol.stats["family choice"] = switching.evidence
    return sol


def _switchable(goal, params):
    """Whether a solve with these options can be done in stretches (else decided once)."""
    return (goal is None and params["dense_output"] is True and params["events"] is None
            and params["breakpoints"] is None and not params["automatic_modeling"]
            and not params["progress"] and params["sample_times"] is None)


class _Switching:
    """The solve in stretches of the module docstring."""

    def __init__(self, solve, ode, base, parameters, params):
        from dolfinode.solve import _absolute_tolerance

        self.solve, self.ode, self.base, self.parameters = solve, ode, base, parameters
        self.rtol = params["tolerance"]
        self.steps_left = params["maximum_steps"]  # a bound on the whole solve, not a stretch
        self.atol = _absolute_tolerance(ode, params["absolute_tolerance"], self.rtol)
        self.current = base
        self.per_element = {}  # the latest CPU time per element of each variant's stretches
        # measured / predicted rate of the last trial of each variant since its last
        # stretch, and its latest uncalibrated prediction
        self.calibration, self.uncalibrated = {}, {}
        self.restart = {}  # the largest restart measured of each variant
        self.evidence = {"stretches": [], "checks": []}

    def other(self, name):
        return "m" + self.base if name == self.base else self.base

    def multi_can_pay(self):
        """Whether m(base) can ever be predicted SWITCH_MARGIN x cheaper than base: its
        predicted elements are at least MULTI_ELEMENTS x those of the fastest component,
        1/N of a mono-adaptive solve's, at COST_RATIO x the cost (no trial has measured the
        ratio before the first prediction), so a small system never pays for stretches."""
        return COST_RATIO * MULTI_ELEMENTS * SWITCH_MARGIN < self.ode.N

    def run(self, samples, stretches=None):
        """Solve [t0, T] in stretches (the first ``stretches`` only, if given), switching;
        the joined Solution."""
        ode = self.ode
        pieces, t, x, step = [], ode.t0, ode.u0, self.parameters.get("initial_time_step")
        length = FIRST_STRETCH * (ode.T - ode.t0) / STRETCH_GROWTH
        costs = []  # (length, CPU time) of the 2nd and 3rd stretches if of one variant
        per_call, shortest = 0.0, 0.0  # the fixed cost of a solve call; a stretch's length
        last = np.inf  # the last stretch's length
        while t < ode.T and (stretches is None or len(pieces) < stretches):
            length = min(length * STRETCH_GROWTH, MAX_STRETCH * (ode.T - ode.t0))
            longest = LONGEST_STRETCH * (ode.T - ode.t0)
            if self.current == self.base:  # a mono-adaptive restart has no start to spread
                longest = min(MAX_STRETCH * (ode.T - ode.t0), STRETCH_GROWTH * last)
            # a multi-adaptive stretch is not followed by one too short to pay its restart
            end = _stretch_end(t, max(length, min(shortest, longest)), ode.T,
                               0.0 if self.current == self.base else shortest)
            piece, cpu = self.stretch(t, end, x, self.current, step)
            last = end - t
            rate = _steady_rate(piece, cpu)
            if 1 <= len(pieces) < 3 and not self.evidence["checks"]:
                costs.append((end - t, cpu))  # (the first carries the steps' growth from 0)
                per_call = _restart_cost(costs) if len(costs) == 2 else 0.0
            if pieces:  # (the first stretch's start is no restart: the steps grow from 0)
                shortest = self.shortest(self.current, cpu, rate, end - t, per_call)
            self.per_element[self.current] = cpu / piece.stats["elements"]
            self.calibration.pop(self.current, None)
            other = self.other(self.current)
            final = end >= ode.T and stretches is None  # nothing left to switch for
            predicted = None if final else self.predicted(other, piece, rate)
            self.evidence["stretches"].append(
                {"method": self.current, "interval": [t, end], "cpu time": cpu, "rate": rate,
                 "predicted rate of " + other: predicted,
                 "cost ratio": None if final else self.cost_ratio()})
            pieces.append(piece)
            t, x = end, piece(end)
            step = _next_step(piece, self.current != self.base)
            if not final and predicted * SWITCH_MARGIN < rate:
                first = (_next_step(piece, False) if piece.multi
                         else _component_steps(piece, self.atol, self.rtol))
                trial, cpu = self.trial(other, t, x, first, min(
                    length * STRETCH_GROWTH, MAX_STRETCH * (ode.T - ode.t0)))
                # a multi-adaptive trial among mono-adaptive stretches is kept only if it
                # continues: else every slab would be joined as N elements, for nothing
                mixes = trial is not None and trial.multi and not any(p.multi for p in pieces)
                if trial is not None and (self.current == other or not mixes):
                    self.evidence["stretches"].append(
                        {"method": other, "interval": [t, trial.ode.T], "cpu time": cpu,
                         "trial": True})
                    pieces.append(trial)
                    t = trial.ode.T
                    x = trial(t)
                    if self.current == other:
                        step = _next_step(trial, other != self.base)
                        check = self.evidence["checks"][-1]
                        shortest = self.shortest(other, cpu, check["measured"],
                                                 t - check["t"], per_call)
                elif trial is not None:
                    self.steps_left += trial.stats["time slabs"]  # solved again
        return _joined(ode, pieces, samples)

    def stretch(self, t, end, x, name, step):
        """(solution, CPU time) of variant ``name`` on [t, end] from x, within the time
        slabs the kept stretches have left of ``maximum_steps``."""
        if self.steps_left < 1:
            raise SolverError(f"maximum_steps reached at t = {t:.6g} (method='auto', in "
                              "stretches): raise maximum_steps or loosen the tolerance", t=t)
        piece, cpu = _solve_on(self.solve, self.ode, t, end, x, name,
                               {**self.parameters, "initial_time_step": step,
                                "maximum_steps": self.steps_left})
        self.steps_left -= piece.stats["time slabs"]
        return piece, cpu

    def shortest(self, name, cpu, rate, length, per_call):
        """:func:`_shortest_stretch` after a stretch of variant ``name``, its restart at least
        the largest measured before (a stretch's start can look cheap where the restart's
        cost spreads over it: the chain's mcG(2) restarts cost about 1 ms each, while the
        second half's rate put some at 0.1 ms)."""
        shortest, self.restart[name] = _shortest_stretch(
            cpu, rate, length, max(per_call, self.restart.get(name, 0.0)))
        return shortest

    def predicted(self, name, piece, rate):
        """The rate of variant ``name`` over the stretch ``piece`` that the other solved at
        ``rate``."""
        if piece.multi:
            other_elements = _mono_elements_late(piece)
        else:
            other_elements = MULTI_ELEMENTS * _multi_elements_late(piece, self.atol, self.rtol)
        ratio = self.cost_ratio()[0]
        predicted = rate * other_elements * (1 / ratio if piece.multi else ratio)
        self.uncalibrated[name] = predicted
        return predicted * self.calibration.get(name, 1.0)

    def cost_ratio(self):
        """(CPU time per multi-adaptive element / per mono-adaptive one, "measured" or
        "prior"): of the latest stretches of both variants, else COST_RATIO."""
        multi, mono = self.per_element.get("m" + self.base), self.per_element.get(self.base)
        return (multi / mono, "measured") if multi and mono else (COST_RATIO, "prior")

    def trial(self, name, t, x, step, length):
        """(solution, CPU time) of variant ``name`` over the next ``length`` from (t, x)
        (None if it failed, the error in the check); ``name`` continues if its rate
        (:func:`_steady_rate`) is below the current one's."""
        stretch = self.evidence["stretches"][-1]
        check = {"t": t, "from": stretch["method"], "rate": stretch["rate"],
                 "predicted": stretch["predicted rate of " + name], "switched": False}
        self.evidence["checks"].append(check)
        try:
            sol, cpu = self.stretch(t, _stretch_end(t, length, self.ode.T), x, name, step)
        except SolverError as error:
            check["error"] = str(error)
            return None, None
        check["measured"] = _steady_rate(sol, cpu)
        self.calibration[name] = check["measured"] / self.uncalibrated[name]
        if check["measured"] < check["rate"]:
            check["switched"] = True
            self.current = name
        return sol, cpu


def _restart_cost(costs):
    """F of the first two stretches' CPU times c_j = F + r L_j: the fixed cost of a stretch
    (the solve's call, its first steps), at least 0 and at most either c_j (timing noise)."""
    (L1, c1), (L2, c2) = costs[:2]
    return min(max((L2 * c1 - L1 * c2) / (L2 - L1), 0.0), c1, c2)


def _shortest_stretch(cpu, rate, length, least):
    """(the shortest stretch whose restart costs at most RESTART_SHARE of it, the restart)
    after one of ``length`` that took ``cpu`` at ``rate`` (:func:`_steady_rate`): the
    restart is its start, cpu - rate x length, or ``least`` (a solve's fixed cost, a
    restart measured before) if larger, and the rest of a stretch costs (cpu - restart) /
    length per unit time."""
    restart = max(cpu - rate * length, least)
    beyond = (cpu - restart) / length
    return (restart / (RESTART_SHARE * beyond) if beyond > 0.0 else np.inf), restart


def _late(sol):
    """The elements (multi-adaptive) or slabs of the solve ``sol`` in the second half of
    its interval: where it has started, and closest to what comes next."""
    return sol.t_start >= 0.5 * (sol.ode.t0 + sol.ode.T)


def _steady_rate(sol, cpu):
    """The CPU rate of the solve ``sol`` (CPU time ``cpu``) at its end: its CPU time per
    element x the elements per unit time of the second half of its interval. A start (the
    steps growing from the first, a multi-adaptive solve's components active until found at
    rest) is paid again by every stretch of either variant, and mostly in a short one; a
    change of scales within the stretch shows in its second half."""
    late = max(int(np.count_nonzero(_late(sol))), 1)
    return cpu / len(sol.t_start) * late / (0.5 * (sol.ode.T - sol.ode.t0))


def _stretch_end(t, length, T, rest=0.0):
    """The end of a stretch of ``length`` from t: T when less than half a stretch, or less
    than ``rest``, would be left after it (no sliver at the end)."""
    return T if T - t - length < max(0.5 * length, rest) else t + length


def _solve_on(solve, ode, t0, T, u0, method, parameters):
    """(solution, CPU time) of ``ode`` solved on [t0, T] from u0 with ``method``.

    The copy shares the declaration's kernels; what its solve derives (a sympy traversal or
    two) is kept on the declaration for the copies made after. u0 is not checked again: a
    value a solve reached may leave a nonnegative domain by atol."""
    shifted = ode._snapshot()
    shifted.__dict__.update(t0=float(t0), T=float(T), u0=np.array(u0, dtype=float))
    clock = _clock()
    sol = solve(shifted, method, **parameters)
    cpu = _clock() - clock
    for name, value in shifted.__dict__.items():
        ode.__dict__.setdefault(name, value)
    return sol, cpu


def _shares(sol, first, atol, rtol):
    """:func:`_step_shares` of the mono-adaptive solution ``sol`` at the ends of its
    slabs ``first``."""
    return _step_shares(sol.values, sol.k, first,
                        np.asarray(sol.method.barycentric_weights, dtype=np.float64),
                        np.asarray(atol, dtype=np.float64), float(rtol))


@njit(cache=True)
def _step_shares(values, k, first, weights, atol, rtol):
    """(eta_ni / max_i eta_ni)^(1/(q+1)), (len(first), N): the share of the mono-adaptive
    step's elements that component i alone would take at the end of slab n = first[s] (1
    where no component has an error), with the local error

        eta_ni = k^(q+1) |u_i^(q+1)| / (atol_i + rtol |U_i|),

    u^(q+1) from the jump of the polynomials' q-th derivatives (the barycentric ``weights``
    applied to the nodal ``values`` (M, q+1, N), over k^q) to the next slab and k the mean of
    the two steps. Compiled: it runs after every stretch, where numpy's per-call cost was
    most of a prediction."""
    q = weights.shape[0] - 1
    N = values.shape[2]
    shares = np.empty((first.shape[0], N))
    for s in range(first.shape[0]):
        n = first[s]
        scale0, scale1 = 1.0 / k[n] ** q, 1.0 / k[n + 1] ** q
        mean = (0.5 * (k[n] + k[n + 1])) ** q
        largest = 0.0
        for i in range(N):
            before, after = 0.0, 0.0
            for j in range(q + 1):
                before += weights[j] * values[n, j, i]
                after += weights[j] * values[n + 1, j, i]
            eta = (abs(after * scale1 - before * scale0) * mean
                   / (atol[i] + rtol * abs(values[n + 1, q, i])))
            shares[s, i] = eta
            largest = max(largest, eta)
        for i in range(N):
            shares[s, i] = (shares[s, i] / largest) ** (1.0 / (q + 1)) if largest > 0.0 else 1.0
    return shares


def _multi_elements_late(sol, atol, rtol, sampled=16):
    """Multi-adaptive elements / mono-adaptive ones over the second half of the
    mono-adaptive solution ``sol`` (:func:`_late`).

    Where the mono-adaptive step k_n meets the largest local error eta_n, component i alone
    would take (eta_ni / max_i eta_ni)^(1/(q+1)) x as many elements (:func:`_step_shares`):
    the mean over i of these shares, over ``sampled`` pairs of consecutive slabs spread over
    the second half.
    """
    M = len(sol.k)
    if M < 2:
        return 1.0
    start = min(int(np.searchsorted(sol.t_start, 0.5 * (sol.ode.t0 + sol.ode.T))), M - 2)
    first = np.arange(start, M - 1, max((M - 1 - start) // sampled, 1))
    return float(_shares(sol, first, atol, rtol).mean())


def _mono_elements_late(sol):
    """Mono-adaptive elements / multi-adaptive ones over the second half of the
    multi-adaptive solution ``sol`` (:func:`_late`): a mono-adaptive step is the smallest
    component step, so its elements are the solve's count of them ("efficiency index" x
    elements) x the share of the fastest component's elements in the second half."""
    late = np.concatenate([[0], np.cumsum(_late(sol))])
    ptr = sol._component_ptr
    fastest_late = (late[ptr[1:]] - late[ptr[:-1]]).max()
    mono = sol.stats["efficiency index"] * sol.stats["elements"]
    return float(mono * fastest_late / np.diff(ptr).max() / max(late[-1], 1))


def _component_steps(sol, atol, rtol):
    """Per component, the first step of a multi-adaptive solve continuing the mono-adaptive
    solution ``sol``: its next step over the component's share at its last elements (at most
    MAX_STEP_GROWTH x), so that the components need not grow their steps from the common one."""
    step = float(sol.stats["next time step"])
    if len(sol.k) < 2:
        return step
    shares = _shares(sol, np.array([len(sol.k) - 2]), atol, rtol)[0]
    return step / np.maximum(shares, 1.0 / MAX_STEP_GROWTH)


def _next_step(sol, per_component):
    """The step the solve ``sol`` would have taken next: per component (multi-adaptive) or
    one (the smallest of a multi-adaptive solve's)."""
    step = sol.stats["next time step"]
    return step if per_component or np.ndim(step) == 0 else float(np.min(step))


def _joined(ode, pieces, samples):
    """One Solution on [t0, T] with ``samples`` equispaced samples of the stretches
    ``pieces``: the mono-adaptive form if all are, else a
    :class:`~dolfinode.solution.MixedSolution` whose shared slabs are the mono-adaptive
    stretches' slabs and the multi-adaptive ones' synchronised slabs, its elements by
    component those of the multi-adaptive stretches (joined into one grouping on first read,
    as a multi-adaptive solve's own)."""
    methods = [piece.stats["method"] for piece in pieces]
    solved = pieces[0].ode._snapshot()
    solved.__dict__.update(t0=ode.t0, T=ode.T, u0=ode.u0)
    stats = {}
    for piece in pieces:
        for key, value in piece.stats.items():
            if isinstance(value, bool):
                stats[key] = stats.get(key, False) or value
            elif isinstance(value, (int, float)) and key not in ("compile time",
                                                                 "efficiency index"):
                stats[key] = stats.get(key, 0) + value
            elif value is not None:
                stats[key] = value
    stats.pop("efficiency index", None)
    stats.pop("next time step", None)
    stats["method"] = " -> ".join(m for i, m in enumerate(methods)
                                  if i == 0 or m != methods[i - 1])
    method = pieces[0].method
    if not any(piece.multi for piece in pieces):
        return Solution(solved, method, np.concatenate([p.t_start for p in pieces]),
                        np.concatenate([p.k for p in pieces]),
                        np.concatenate([p.values for p in pieces]), stats, samples)
    parts = [_parts(piece) for piece in pieces]
    # each component's elements, piece after piece: component i's elements of piece p start
    # at ptr[i] + (component i's elements in the pieces before p)
    counts = np.array([np.diff(elements[0]) for elements, _ in parts])  # (pieces, N)
    slabs = [np.concatenate(part) for part in zip(*(slabs for _, slabs in parts))]
    stats["elements per component"] = counts.sum(axis=0) + len(slabs[0])
    ptr = np.concatenate([[0], np.cumsum(counts.sum(axis=0))])
    offsets = ptr[:-1] + np.cumsum(counts, axis=0) - counts
    t_start, t_end = np.empty(ptr[-1]), np.empty(ptr[-1])
    values = np.empty((ptr[-1], method.q + 1))
    for (elements, _), offset in zip(parts, offsets):
        _place_elements(offset, *elements, t_start, t_end, values)
    if len(slabs[0]) == 0:
        sol = Solution.grouped(solved, method, ptr, t_start, t_end, values, stats, samples)
    else:
        sol = MixedSolution(solved, method, (ptr, t_start, t_end, values), slabs, stats,
                            samples)
    # (U inside the elements: mcG(q)'s dense value in the joined form would test the
    # defect of a mono-adaptive stretch's cG(q) slab otherwise than its own evaluation)
    sol._rhs = None
    return sol


def _parts(sol):
    """((ptr, t_start, t_end, values) of the elements by component, (s_start, s_end,
    s_values) of the shared slabs) of a stretch, without joining a MixedSolution's parts."""
    declared, nn = sol._declaration, sol.method.q + 1  # (not sol.ode: made when read)
    N = declared.N
    if not sol.multi:
        end = np.append(sol.t_start[1:], declared.T)
        return ((np.zeros(N + 1, dtype=np.int64), np.empty(0), np.empty(0),
                 np.empty((0, nn))), (sol.t_start, end, sol.values))
    parts = sol.__dict__.get("_parts")
    if parts is not None:
        return parts[:4], parts[4:]
    return ((sol._component_ptr, sol.t_start, sol._t_end, sol.values),
            (np.empty(0), np.empty(0), np.empty((0, nn, N))))


@njit(cache=True)
def _place_elements(offset, ptr, t_start, t_end, values, out_t_start, out_t_end, out_values):
    """Copy component i's elements ptr[i]:ptr[i + 1] of a multi-adaptive solution to the
    rows from offset[i] of the out arrays."""
    for i in range(offset.shape[0]):
        row = offset[i]
        for e in range(ptr[i], ptr[i + 1]):
            out_t_start[row], out_t_end[row] = t_start[e], t_end[e]
            for j in range(values.shape[1]):  # (by entry, not slices: see io.history)
                out_values[row, j] = values[e, j]
            row += 1
