"""``method="auto"``: the mono- or multi-adaptive variant of a method, switched between as
the problem's scales change.

A multi-adaptive element costs several mono-adaptive component-steps (its own moments,
sweeps and partition): mcG(q)/mdG(q) pay off only where the components' steps spread
widely, and the spread may change during a solve (a fast oscillation excited later, a
transient that dies out). [t0, T] is solved in stretches, the first FIRST_STRETCH (T - t0)
long with the mono-adaptive variant (cheap to start), each next one STRETCH_GROWTH x longer
up to MAX_STRETCH (T - t0) (a problem that never changes pays for five restarts), each from
the end value of the last with its last step. After each stretch the current variant's rate
r = CPU time / length is measured and the other's predicted from the elements it would take
over the same stretch,

    r_other = r x (E_other / E) x (c_other / c),

with c the CPU time per element: E_mono = (efficiency index) x E of a multi-adaptive stretch
(a mono-adaptive step is the smallest component step); E_multi of a mono-adaptive stretch
from the spread of its components' local errors (:func:`_multi_elements`); c_multi / c_mono
the latest ratio measured on stretches, COST_RATIO before both were; r_other is scaled by
c = measured / predicted of the last check of the other variant (until it runs a stretch;
c > 1 is taken as the variant's start, spread over that pilot's length h: the next pilot, of
length L, has 1 + (c - 1) h / L). When r_other < r / SWITCH_MARGIN, the other variant is
measured from the current state by a pilot as long as the last stretch (a quarter of the
next), and it takes over only if its rate, fixed cost per call and start included, is below
r / SWITCH_MARGIN: a hysteresis, so that timing noise cannot make a problem that does not
change switch back and forth. The pilot is then the first stretch of the new variant. The
stretches, checks and switches with their evidence are in ``sol.stats["family choice"]``; a
solution with stretches of both variants is represented in the multi-adaptive form (a
mono-adaptive slab is one element per component: mcG(q) on a common partition is cG(q)), so
evaluation, samples and ``estimate_error`` see one solution.

Decided once (after the first stretch and its check, the chosen variant solving [t0, T]
from the start): with a goal, events, breakpoints, automatic modeling, a progress bar,
sample times, or a history kept only as samples or in a file.

Limitation: a change of scales is seen at the end of the stretch it happens in (up to 29 %
of [t0, T] later), and the prediction of the multi-adaptive elements is a heuristic
(0.4-0.55 x the elements mcG(2) took on the benchmark problems, whence MULTI_ELEMENTS):
a variant predicted no cheaper is not measured.
"""
import itertools
import re
import time

import numpy as np

from dolfinode.compile import lower
from dolfinode.errors import SolverError
from dolfinode.solution import Solution

#: "auto" is "auto:cG(2)"; "auto:cG(q)" and "auto:dG(q)" switch between cG(q)/mcG(q), dG(q)/mdG(q).
_AUTO_PATTERN = re.compile(r"^\s*auto\s*(?::\s*((?:cG|dG)\(\s*\d+\s*\)))?\s*$", re.IGNORECASE)
DEFAULT_BASE = "cG(2)"
#: The first stretch and the longest, as fractions of T - t0, and the growth of the next ones
#: (1, 4, 16, 25, 25, 29 %: a change is seen within 29 % of [t0, T]).
FIRST_STRETCH, MAX_STRETCH, STRETCH_GROWTH = 1e-2, 0.25, 4
#: The other variant is measured when predicted, and takes over when measured, more than
#: SWITCH_MARGIN x cheaper than the current one (timing noise of a shared machine is some
#: 10-30 %).
SWITCH_MARGIN = 1.5
#: CPU time per multi-adaptive element / per mono-adaptive one until both were measured: the
#: smallest measured on the benchmark problems (11-22 on those of doc/benchmarks/auto.md), so
#: that a multi-adaptive variant is rather measured than missed.
COST_RATIO = 12.0
#: Multi-adaptive elements / :func:`_multi_elements`' estimate (0.4-0.55 x on the benchmarks).
MULTI_ELEMENTS = 2.0
#: Parameters a stretch overrides: output, progress, modeling and events are the whole
#: solve's business (sample times and a history file refer to [t0, T]).
_STRETCH_PARAMETERS = {"number_of_samples": 2, "sample_times": None, "dense_output": True,
                       "progress": False, "automatic_modeling": False, "events": None}
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
        chosen once), "stretches" (per stretch: method, interval, CPU time, rate and the
        other's predicted rate), "checks" (per measurement of the other variant: time, the
        current, predicted and measured rates, whether it switched, or the pilot's error)
        and, when decided once, "decided once".
    """
    lower(ode)  # compiled once, shared by the stretches (a copy would compile again)
    switching = _Switching(solve, ode, base, {**parameters, **_STRETCH_PARAMETERS}, params)
    if _switchable(goal, params):
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
        # (measured / predicted rate, pilot length) of the last check of each variant since
        # its last stretch, and its latest uncalibrated prediction
        self.calibration, self.uncalibrated = {}, {}
        self.evidence = {"stretches": [], "checks": []}

    def other(self, name):
        return "m" + self.base if name == self.base else self.base

    def run(self, samples, stretches=None):
        """Solve [t0, T] in stretches (the first ``stretches`` only, if given), switching;
        the joined Solution."""
        ode = self.ode
        pieces, t, x, step = [], ode.t0, ode.u0, self.parameters.get("initial_time_step")
        length = FIRST_STRETCH * (ode.T - ode.t0) / STRETCH_GROWTH
        while t < ode.T and (stretches is None or len(pieces) < stretches):
            length *= STRETCH_GROWTH
            length = min(length, MAX_STRETCH * (ode.T - ode.t0))
            end = ode.T if ode.T - t < 1.5 * length else t + length  # (no sliver at the end)
            piece, cpu = self.stretch(t, end, x, self.current, step)
            rate = cpu / (end - t)
            self.per_element[self.current] = cpu / piece.stats["elements"]
            self.calibration.pop(self.current, None)
            other = self.other(self.current)
            predicted = self.predicted(other, piece, rate)
            self.evidence["stretches"].append(
                {"method": self.current, "interval": [t, end], "cpu time": cpu, "rate": rate,
                 "predicted rate of " + other: predicted})
            pieces.append(piece)
            self.steps_left -= piece.stats["time slabs"]
            t, x = end, piece(end)
            step = _next_step(piece, self.current != self.base)
            if predicted * SWITCH_MARGIN < rate and (t < ode.T or stretches is not None):
                pilot = self.measure(other, t, x, _next_step(piece, False), length)
                if pilot is not None:
                    pieces.append(pilot)
                    self.steps_left -= pilot.stats["time slabs"]
                    self.current = other
                    t = pilot.ode.T
                    x, step = pilot(t), _next_step(pilot, other != self.base)
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
        return piece, cpu

    def predicted(self, name, piece, rate):
        """The rate of variant ``name`` over the stretch ``piece`` that the other solved at
        ``rate``."""
        elements = piece.stats["elements"]
        if piece.multi:  # a mono-adaptive step would be the smallest component step
            other_elements = piece.stats["efficiency index"] * elements
        else:
            other_elements = MULTI_ELEMENTS * _multi_elements(piece, self.atol, self.rtol)
        multi, mono = self.per_element.get("m" + self.base), self.per_element.get(self.base)
        ratio = multi / mono if multi and mono else COST_RATIO
        predicted = rate * other_elements / elements * (1 / ratio if piece.multi else ratio)
        self.uncalibrated[name] = predicted
        if name in self.calibration:
            # the excess of a check's measured over its predicted rate is the variant's
            # start, spread over that pilot's length; the next pilot is as long as ``piece``
            excess, pilot = self.calibration[name]
            length = piece.ode.T - piece.ode.t0
            predicted *= excess if excess < 1 else 1 + (excess - 1) * min(1.0, pilot / length)
        return predicted

    def measure(self, name, t, x, step, length):
        """Measure variant ``name`` by a pilot from (t, x) over ``length``: its solution if
        it takes over, else None (the check in the evidence)."""
        stretch = self.evidence["stretches"][-1]
        check = {"t": t, "from": stretch["method"], "rate": stretch["rate"],
                 "predicted": stretch["predicted rate of " + name], "switched": False}
        self.evidence["checks"].append(check)
        end = min(t + length, self.ode.T)
        try:
            sol, cpu = self.stretch(t, end, x, name, step)
        except SolverError as error:
            check["error"] = str(error)
            return None
        # the mean rate, fixed cost per call and start included: a change must pay for them
        check["measured"] = cpu / (end - t)
        self.calibration[name] = (check["measured"] / self.uncalibrated[name], end - t)
        if check["measured"] * SWITCH_MARGIN < check["rate"]:
            check["switched"] = True
            self.evidence["stretches"].append({"method": name, "interval": [t, end],
                                               "cpu time": cpu})
            return sol
        return None


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


def _multi_elements(sol, atol, rtol, sampled=64):
    """The elements a multi-adaptive solve would take over the mono-adaptive solution ``sol``.

    The local error of component i on element n is taken as
    eta_ni = k_n^(q+1) |u_i^(q+1)| / (atol_i + rtol |U_i|), with u^(q+1) from the jump of
    the polynomials' q-th derivatives between consecutive elements; where the mono-adaptive
    step k_n meets the largest eta_n, component i alone would take
    (eta_ni / max_i eta_ni)^(1/(q+1)) x as many elements. Summed over ``sampled`` pairs of
    consecutive elements spread over the solution, scaled to all of them.
    """
    q, M = sol.method.q, len(sol.k)
    if M < 2:
        return float(sol.stats["elements"])
    pairs = np.unique(np.linspace(0, M - 2, min(sampled, M - 1)).astype(np.int64))
    both = np.concatenate([pairs, pairs + 1])
    k = sol.k[both].reshape(2, -1)
    values = sol.values[both].reshape(2, len(pairs), q + 1, -1)
    leading = sum(w * values[:, :, j] for j, w in enumerate(sol.method.barycentric_weights))
    leading /= k[..., None] ** q
    eta = np.abs(leading[1] - leading[0]) * (0.5 * (k[0] + k[1]))[:, None] ** q
    eta /= atol + rtol * np.abs(values[1, :, -1, :])
    largest = eta.max(axis=1, keepdims=True)
    share = np.divide(eta, largest, out=np.ones_like(eta), where=largest > 0) ** (1.0 / (q + 1))
    return float(share.sum(axis=1).mean() * M)


def _component_blocks(sol):
    """Per component, its (t_start, t_end, values) in ``sol`` (views; a mono-adaptive
    solution's elements end exactly where the next starts, the last at T)."""
    if sol.multi:
        ptr = sol._component_ptr
        return [(sol.t_start[a:b], sol._t_end[a:b], sol.values[a:b])
                for a, b in itertools.pairwise(ptr)]
    t_end = np.append(sol.t_start[1:], sol.ode.T)
    return [(sol.t_start, t_end, sol.values[:, :, i]) for i in range(sol.ode.N)]


def _next_step(sol, per_component):
    """The step the solve ``sol`` would have taken next: per component (multi-adaptive) or
    one (the smallest of a multi-adaptive solve's)."""
    step = sol.stats["next time step"]
    return step if per_component or np.ndim(step) == 0 else float(np.min(step))


def _joined(ode, pieces, samples):
    """One Solution on [t0, T] with ``samples`` equispaced samples of the stretches
    ``pieces``: the mono-adaptive form if all are, else the multi-adaptive one."""
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
    # each component's elements, piece after piece (views joined once: no sort, no transpose)
    blocks = [_component_blocks(piece) for piece in pieces]
    ordered = [piece_blocks[i] for i in range(ode.N) for piece_blocks in blocks]
    t_start, t_end, values = (np.concatenate([block[j] for block in ordered]) for j in range(3))
    counts = np.array([len(block[0]) for block in ordered]).reshape(ode.N, len(pieces))
    stats["elements per component"] = counts.sum(axis=1)
    ptr = np.concatenate([[0], np.cumsum(stats["elements per component"])])
    return Solution.grouped(solved, method, ptr, t_start, t_end, values, stats, samples)


