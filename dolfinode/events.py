"""Discontinuities and events: breakpoints of f(t), switches on the state, and events g(u, t).

A right-hand side with a non-smooth function (Piecewise, Heaviside, sign, floor, ceiling;
Abs, Min, Max, except a kink whose continuation could leave f's domain, see
:func:`_unsafe_kinks`) is rewritten as a smooth one whose branch is a parameter sigma_j
(:func:`switched`): Heaviside(g) -> sigma_j, Abs(g) -> sigma_j g, a condition g < 0 ->
sigma_j > 1/2, and so on. On each piece of [t0, T] where no switching function g_j changes
sign, the solver integrates this smooth f with sigma fixed: no element straddles a jump and
every stage (for dG also the end node) is on the branch of its piece, which a loop evaluating
the original f at t_n + k would not be. Switching functions of t alone give the breakpoints
(their roots, solved by sympy, plus the user's ``breakpoints=``); those on the state are
located like events, on the Galerkin polynomial, and the element is re-integrated to the
crossing where the next piece starts on the other branch; the crossing's time is then
corrected until g vanishes at that element's end, where the solution superconverges.

Events g(u, t) (:class:`Event`) are located on the Galerkin polynomials: g is sampled at the
element ends (of the components it depends on) of each chunk the compiled loop returns, as
solve_ivp samples it at its steps (two crossings inside one element are not seen), and each
sign change is refined by the Illinois method on the polynomials to 1e-13 relative. The first
crossing of a terminal event or a state switch is located at once: a terminal event ends the
solve there (the element containing it is re-integrated to end there, the time corrected
as for a switch). The others are
located after the solve, on the final solution, all at once.
"""
import copy
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import sympy as sp
from numba import njit
from scipy.optimize import brentq
from sympy.functions.elementary.piecewise import ExprCondPair

from dolfinode.features import MIN_WIDTH, Features, Unbounded, enclose, narrow_features
from dolfinode.ode import ODE
from dolfinode.ode import t as time_symbol
from dolfinode.solution import Solution, branches_taken
from dolfinode.timeslab import smallest_step

#: Consecutive switches less than SLIDING_SPAN x (T - t0) apart after which a state switch is
#: taken as a sliding mode (the flow on both sides pushes towards g = 0).
SLIDING_SWITCHES, SLIDING_SPAN = 50, 1e-9
#: Most Illinois iterations locating an event (it converges superlinearly; a crossing in a
#: dG jump, where g is discontinuous, takes longest), and the relative width to reach: some
#: 500 ulp, where g's rounding starts to decide its sign (closer, rounding stalls the
#: iteration for several times the usual count).
_ROOT_ITERATIONS = 200
_ROOT_RTOL = 1e-13
#: Most breakpoints of a floor/ceiling of t (each one ends a piece of the integration).
MAX_BREAKPOINTS = 100_000
#: Times at which a switching function of t that sympy cannot solve is sampled for its roots,
#: and the pieces a grid cell that may hide two roots is split into (:func:`_sampled_roots`).
ROOT_GRID = 2**16 + 1
ROOT_SPLIT = 16
_SWITCH = "dn_switch_"


class Event:
    """An event: a zero crossing of g(u, t), located on the Galerkin solution.

    Parameters
    ----------
    g : sympy expression
        In the states, ``dn.t`` and the ODE's parameters.
    terminal : bool
        Whether the solve ends at the first crossing (``sol.status == 1``).
    direction : {0, 1, -1}
        Only crossings where g increases (1) or decreases (-1); 0: both (as solve_ivp).
    """

    def __init__(self, g, terminal=False, direction=0):
        try:
            self.g = sp.sympify(g)
        except (sp.SympifyError, TypeError):
            raise TypeError(f"an event is a sympy expression g(u, t), got {g!r}") from None
        if not isinstance(self.g, sp.Expr):
            raise TypeError(f"an event is a sympy expression g(u, t), got {g!r}")
        if self.g.has(sp.I, sp.zoo, sp.nan, sp.oo, sp.S.NegativeInfinity):
            raise ValueError(f"an event is a finite real expression g(u, t), got {self.g}")
        if not isinstance(terminal, (bool, np.bool_)):
            raise TypeError(f"terminal must be True or False, got {terminal!r}")
        if direction not in (0, 1, -1):
            raise ValueError(f"direction must be 0, 1 or -1, got {direction!r}")
        self.terminal, self.direction = bool(terminal), int(direction)

    def __repr__(self):
        return f"Event({self.g}, terminal={self.terminal}, direction={self.direction})"


@dataclass
class Switch:
    """A switching function g of f and the parameter sigma that holds its branch: sigma is
    ``positive`` where g > 0, ``negative`` where g < 0 and ``at_zero`` where g = 0 (the
    original function's value there). ``floor``: sigma is floor(g) (a floor or ceiling of
    t: ceiling(g) = -floor(-g))."""

    g: sp.Expr
    symbol: sp.Symbol
    positive: float = 1.0
    negative: float = 0.0
    at_zero: float = 1.0
    floor: bool = False
    #: A kink of the state (Abs, Min, Max): f is continuous across g = 0, so its crossings
    #: are counted apart from the jumps' and cannot be a sliding mode.
    kink: bool = False

    def value(self, g):
        if self.floor:
            return float(math.floor(g))
        return self.positive if g > 0 else self.negative if g < 0 else self.at_zero


def _relational(rel, symbol):
    """(switch, replacement) of a condition lhs < rhs etc.: g = lhs - rhs, sigma its truth."""
    g = rel.lhs - rel.rhs
    truth = {sp.StrictLessThan: (0.0, 1.0, 0.0), sp.LessThan: (0.0, 1.0, 1.0),
             sp.StrictGreaterThan: (1.0, 0.0, 0.0), sp.GreaterThan: (1.0, 0.0, 1.0)}[type(rel)]
    return Switch(g, symbol, *truth), sp.StrictGreaterThan(symbol, sp.Rational(1, 2))


def _replacement(atom, symbol):
    """(switch, smooth replacement) of one non-smooth function, or None."""
    if isinstance(atom, (sp.StrictLessThan, sp.LessThan, sp.StrictGreaterThan,
                         sp.GreaterThan)):
        return _relational(atom, symbol)
    if isinstance(atom, sp.Heaviside):
        h0 = atom.args[1] if len(atom.args) > 1 else sp.S.Half
        return Switch(atom.args[0], symbol, 1.0, 0.0, float(h0)), symbol
    if isinstance(atom, sp.sign):
        return Switch(atom.args[0], symbol, 1.0, -1.0, 0.0), symbol
    if isinstance(atom, sp.Abs):
        return Switch(atom.args[0], symbol, 1.0, -1.0, 0.0), symbol * atom.args[0]
    if isinstance(atom, (sp.Min, sp.Max)) and len(atom.args) == 2:
        a, b = atom.args
        larger = 1.0 if isinstance(atom, sp.Max) else 0.0  # sigma = 1 selects a
        return (Switch(a - b, symbol, larger, 1.0 - larger, 1.0),
                symbol * a + (1 - symbol) * b)
    if isinstance(atom, sp.floor):
        return Switch(atom.args[0], symbol, floor=True), symbol
    if isinstance(atom, sp.ceiling):
        return Switch(-atom.args[0], symbol, floor=True), -symbol
    return None


def _binary(expr):
    """Min/Max of more than two arguments as nested pairs."""
    def nest(e):
        return e.func(e.args[0], e.func(*e.args[1:], evaluate=False), evaluate=False)
    return expr.replace(lambda e: isinstance(e, (sp.Min, sp.Max)) and len(e.args) > 2, nest)


def switched(ode):
    """The ODE with every non-smooth function of f replaced by a smooth one of a branch
    parameter, and its :class:`Switch` es; (ode, []) when there is none.

    The parameters are named dn_switch_0, dn_switch_1, ... and follow the ODE's own, so that
    ``compiled.p[len(ode.params) + j]`` holds sigma_j.
    """
    if hasattr(ode, "templates"):
        jumps = ode._derived("_jumps", ode.templates, lambda: _template_jumps(ode))
        if jumps:
            from dolfinode.solve import _warn  # (solve imports this module)

            _warn(f"the template term {jumps[0]} jumps ({', '.join(map(str, jumps[1]))}): "
                  "templates do not locate jumps in t or switches on the state, and the "
                  "step control and the error estimate step over them (dG(1) on x' = "
                  "Heaviside(x - 0.5) + 1 was 0.11 off at tolerance 1e-6, estimated 3e-18). "
                  "Declare the system with dn.ODE, which locates them, give a jump in t as "
                  "breakpoints=[...], or smooth the switch (tanh(g / eps))")
        return ode, []
    # made once per declaration (a sympy traversal of every right-hand side)
    rhs, switches = ode._derived("_smooth", ode.rhs, lambda: _smooth(ode))
    if not switches:
        return ode, []
    params = dict(ode.params)
    params.update({s.symbol: s.value(0.0) for s in switches})
    smooth = ODE(dict(zip(ode.states, rhs)), ode.u0, ode.T, params, ode.t0, ode.nonnegative)
    return smooth, switches


def _template_jumps(ode):
    """(term, its non-smooth atoms) of the first template term of ``ode`` that jumps (as
    :func:`_smooth` counts them: a kink of the state is left to the step control), or None."""
    for template in ode.templates:
        for _, term in template.terms:
            atoms = [a for a in term.atoms(*NON_SMOOTH)
                     if not (isinstance(a, _KINKS) and a.free_symbols & set(template.slots))]
            if atoms:
                return term, sorted(atoms, key=str)
    return None


def _smooth(ode):
    """(right-hand sides, switches) of :func:`switched`."""
    if not any(e.has(*NON_SMOOTH) for e in ode.rhs):
        return ode.rhs, []
    switches, done, states = [], {}, set(ode.states)
    unsafe = _unsafe_kinks([_binary(expr) for expr in ode.rhs], states)
    for expr in ode.rhs:
        # innermost first: a switch inside another's argument is smooth when that one is
        for atom in sorted(_binary(expr).atoms(*NON_SMOOTH, sp.Rel), key=sp.count_ops):
            symbol = sp.Symbol(f"{_SWITCH}{len(switches)}", real=True)
            kink = bool(isinstance(atom, _KINKS) and atom.free_symbols & states)
            skip = atom in done or (kink and atom in unsafe)
            made = None if skip else _replacement(atom, symbol)
            if made is not None:
                # g in the original functions (evaluated as such); f smooth in sigma
                made[0].kink = kink
                switches.append(made[0])
                # an unsafe kink of t stays in f (continuous: its roots end the pieces)
                done[atom] = (atom.xreplace(done) if atom in unsafe
                              else _replacement(atom.xreplace(done), symbol)[1])
    return [_binary(expr).xreplace(done) for expr in ode.rhs], switches


def _unsafe_kinks(exprs, states):
    """The kinks (Abs, Min, Max) in ``exprs`` whose continuation sigma g past the kink may
    leave f's domain: those reached from a root through any function but Add, Mul, a power
    by a nonnegative integer, an entire function (``_ENTIRE``), another non-smooth function
    or a condition (sqrt(|u - a|) would be the square root of a negative number, 1/|u| could
    divide by zero). A kink of the state among them is left to the step control; one of t
    alone stays in f as it is, and its roots still end the pieces (a continuation would be
    evaluated at a root rounded to the other side: sqrt(-sin(2 t)) at t = fl(pi/2))."""
    unsafe = set()

    def walk(e, safe):
        if isinstance(e, _KINKS) and not safe:
            unsafe.add(e)
        for i, arg in enumerate(e.args):
            keeps = (isinstance(e, (sp.Add, sp.Mul, *_ENTIRE, *NON_SMOOTH, sp.Rel,
                                    ExprCondPair))
                     or (isinstance(e, sp.Pow) and i == 0 and e.exp.is_Integer
                         and e.exp >= 0))
            walk(arg, safe and keeps)

    for expr in exprs:
        walk(expr, True)
    return unsafe


#: Continuous functions with a kink: of t they give breakpoints; of the state they are
#: located as switches (:class:`Switch` ``kink``), unless the smooth continuation sigma g
#: past the kink may leave f's domain (:func:`_unsafe_kinks`): those are left to the step
#: control, where the order drops to about 1 at the kink (those of t stay in f).
_KINKS = (sp.Abs, sp.Min, sp.Max)
#: Functions analytic on the whole real line: a kink inside one is located.
_ENTIRE = (sp.sin, sp.cos, sp.exp, sp.sinh, sp.cosh, sp.tanh, sp.atan, sp.erf, sp.erfc)
NON_SMOOTH = (sp.Piecewise, sp.Heaviside, sp.sign, sp.Abs, sp.Min, sp.Max, sp.floor,
               sp.ceiling)


def _numeric(expr, ode):
    """``expr`` with the parameter values substituted (the switches' own are left)."""
    return sp.sympify(expr).xreplace({s: sp.Float(v) for s, v in ode.params.items()})


def _roots_in(g, t0, T):
    """The real roots of g(t) in (t0, T), sorted: sympy's, or where sympy cannot solve for
    them, :func:`_sampled_roots`.

    Raises ValueError for more than MAX_BREAKPOINTS roots."""
    periodic = _periodic_roots(g, t0, T)
    if periodic is not None:
        return periodic
    try:
        roots = sp.solveset(g, time_symbol, sp.Interval.open(t0, T))
    except (NotImplementedError, ValueError, TypeError):
        roots = None
    if roots is sp.S.EmptySet:
        return []
    if isinstance(roots, sp.FiniteSet):
        return sorted(float(r) for r in roots if r.is_real)
    return _sampled_roots(g, t0, T)


def _sampled_roots(g, t0, T):
    """The roots of g in [t0, T] from its sign changes on ROOT_GRID equispaced times, each
    refined by Brent's method to rounding. Two roots inside one cell (a window of t
    narrower than the grid) leave no sign change; so a cell whose ends have one sign but
    whose interval enclosure holds 0 is sampled again (:func:`_sampled`): the windows
    left out of sin(t^2) > 1 - 1e-5 on [0, 20] (5 of 64) were lost from the solution and
    from the reference its error is measured against."""
    def hides_roots(start, end, low, high):
        return (start * end > 0) & (low <= 0) & (high >= 0)

    roots = []
    for function, times, values in _sampled(g, t0, T, ROOT_GRID - 1, hides_roots):
        sign = np.sign(values)
        roots += times[sign == 0].tolist()
        change = np.flatnonzero((sign[:, :-1] * sign[:, 1:]).ravel() < 0)
        left, right = times[:, :-1].ravel(), times[:, 1:].ravel()
        roots += [brentq(function, left[i], right[i], xtol=1e-300) for i in change]
    return sorted(set(roots))


def _range(g, t0, T):
    """(lowest, highest) value of g on [t0, T] to the integer levels that matter to
    floor(g): its values on 1000 cells, and on the cells whose interval enclosure reaches
    an integer level beyond them, sampled again (:func:`_sampled`): the levels of a spike
    between samples (floor(10 exp(-((t - 3.0037) / 1e-3)^2))) were missed."""
    bounds = [np.inf, -np.inf]

    def beyond(start, end, low, high):
        return (low < math.floor(bounds[0]) - 1) | (high > math.ceil(bounds[1]) + 1)

    for _, _, values in _sampled(g, t0, T, 1000, beyond):
        bounds = [min(bounds[0], np.min(values)), max(bounds[1], np.max(values))]
    return bounds


def _sampled(g, t0, T, n, doubtful):
    """(function, times, values) of g: on n equal cells of [t0, T] (times (1, n + 1)), then,
    round after round, on each cell that ``doubtful(g at its start, g at its end, low,
    high)`` flags (low, high: g's interval bounds on it, :func:`~dolfinode.features.enclose`)
    split ROOT_SPLIT-fold (times (cells, ROOT_SPLIT + 1)), down to MIN_WIDTH (T - t0).
    Sampling alone sees nothing between two samples; the bounds hold over the whole cell.
    It stops where g has no bounds (atan2) or more than ROOT_GRID cells are in doubt (bounds
    too loose to decide)."""
    function = sp.lambdify(time_symbol, g, "numpy")
    a, b = np.array([t0]), np.array([T])
    while a.size:
        times = a[:, None] + (b - a)[:, None] * np.linspace(0.0, 1.0, n + 1)
        times[:, -1] = b
        values = function(times) * np.ones_like(times)
        yield function, times, values
        left, right = times[:, :-1].ravel(), times[:, 1:].ravel()
        wide = right - left > MIN_WIDTH * (T - t0)
        try:
            low, high = enclose(g, left[wide], right[wide])
        except Unbounded:
            return
        doubt = doubtful(values[:, :-1].ravel()[wide], values[:, 1:].ravel()[wide], low, high)
        if np.count_nonzero(doubt) > ROOT_GRID:
            return
        a, b, n = left[wide][doubt], right[wide][doubt], ROOT_SPLIT


def _periodic_roots(g, t0, T):
    """The roots in (t0, T), sorted, where sympy's general solution is finite or a union of
    families t = a n + b over the integers n (a zero of sin or cos of a linear function of
    t), else None. sympy enumerates such families on an interval one root at a time (40 s for the
    31,830 roots of sin(1e4 t) on [0, 10]); here they are counted first."""
    try:
        general = sp.solveset(g, time_symbol, sp.S.Reals)
    except (NotImplementedError, ValueError, TypeError):
        return None
    if isinstance(general, sp.FiniteSet):
        return sorted(r for r in (float(r) for r in general if r.is_real) if t0 < r < T)
    families = general.args if isinstance(general, sp.Union) else (general,)
    lines = []
    for family in families:
        if not isinstance(family, sp.ImageSet) or family.base_set != sp.S.Integers:
            return None
        n = family.lamda.variables[0]
        a, b = sp.diff(family.lamda.expr, n), family.lamda.expr.subs(n, 0)
        if not (a.is_number and b.is_number and a.is_real and b.is_real and a != 0):
            return None
        lines.append((abs(float(a)), float(b)))
    count = sum((T - t0) / a for a, _ in lines)
    if count > MAX_BREAKPOINTS:
        raise ValueError(f"{g} changes sign about {count:.3g} times on [t0, T], more than "
                         f"{MAX_BREAKPOINTS} breakpoints: smooth it (by its average, for a "
                         "fast switching), or split the solve")
    roots = [b + a * np.arange(math.ceil((t0 - b) / a), math.floor((T - b) / a) + 1)
             for a, b in lines]
    roots = np.sort(np.concatenate(roots))
    roots = roots[(roots > t0) & (roots < T)]
    # a root of two families (sin(10 t) cos(3 t) at pi/2) once, though they round apart
    apart = np.diff(roots) > 64 * np.finfo(float).eps * np.maximum(abs(t0), abs(T))
    return roots[np.append(True, apart)].tolist() if roots.size else []


def breakpoints(ode, switches, given, edges=()):
    """Sorted breakpoints in (t0, T): roots of the switching functions of t alone, the
    user's ``given`` and the ``edges`` of narrow features of f(t) (times outside (t0, T)
    are dropped). The pieces between the jumps (roots and ``given``) are checked by
    :func:`_check_pieces`; the features' edges, which grade steps down to a singular point,
    are not jumps."""
    t0, T = ode.t0, ode.T
    times = []
    for s in switches:
        g = _numeric(s.g, ode)
        if g.free_symbols - {time_symbol}:
            continue
        if not s.floor:
            times += _roots_in(g, t0, T)
            continue
        low, high = _range(g, t0, T)
        low, high = math.floor(low) - 1, math.ceil(high) + 1
        if high - low > MAX_BREAKPOINTS:
            raise ValueError(f"floor/ceiling of {s.g} jumps more than {MAX_BREAKPOINTS} times "
                             "on [t0, T]: smooth it, or split the solve")
        for n in range(low, high + 1):
            times += _roots_in(g - n, t0, T)
    times = np.union1d(times, _not_found(np.asarray(given, dtype=float), times, T - t0))
    times = times[(times > t0) & (times < T)]
    _check_pieces(np.concatenate([[t0], times, [T]]), T - t0)
    times = np.union1d(times, np.asarray(edges, dtype=float))
    return times[(times > t0) & (times < T)]


def _not_found(given, found, span):
    """The ``given`` breakpoints that are not a jump ``found`` in the declaration: one within
    the smallest step of a root is that root, rounded apart (pi / 3 given for sign(sin(3 t))
    lies 2 ulp from the root found, and made a piece too short to integrate)."""
    if not len(found):
        return given
    found = np.sort(np.asarray(found, dtype=float))
    right = np.minimum(np.searchsorted(found, given), found.size - 1)
    left = np.maximum(right - 1, 0)  # (the found roots on either side of each given time)
    gap = np.minimum(abs(given - found[left]), abs(given - found[right]))
    return given[gap >= smallest_step.py_func(given, span)]


def _check_pieces(ends, span):
    """Raise ValueError for a piece [a, b] between jumps of f(t) that the loops cannot
    integrate: one with no double inside (f's branches there are read at its middle), or
    one that ends at a jump and is shorter than the smallest step double precision
    resolves at a: the step after it, started from its length, stopped the solve with a
    step below that (a jump at 1e-300 from t0 = 0), or the piece was lost (a pulse 16 ulp
    wide at t = 1)."""
    a, b = ends[:-1], ends[1:]
    middle = 0.5 * (a + b)
    short = (b - a < smallest_step.py_func(a, span)) & (b < ends[-1])
    bad = np.flatnonzero((middle <= a) | (middle >= b) | short)
    if bad.size:
        n = bad[0]
        raise ValueError(f"the piece [{float(a[n])!r}, {float(b[n])!r}] of f(t) between its "
                         "jumps (or t0) is shorter than the smallest step double precision "
                         "resolves there "
                         f"({smallest_step(a[n], span):.2g}): f cannot be integrated on it. Move "
                         "the jumps apart (a pulse wider than that), merge them, or put a jump "
                         "this close to t0 at t0")


def _sin_pi(g):
    """sin(pi g), zero exactly where g is an integer (numpy's sin(pi n) is about 1e-16 n, of
    either sign): its sign changes are where floor(g) jumps."""
    n = np.round(g)
    return np.where(n % 2 == 0, 1.0, -1.0) * np.sin(np.pi * (g - n))


class Detector:
    """Sign changes of functions g_j(u, t) on the Galerkin solution, chunk by chunk.

    ``last[j]`` is the sign of g_j before the next chunk (0: not yet known, as at t0 where
    a zero is not an event). The last ``switches`` functions are switches of f: for them the
    first nonzero sign after a zero start is a crossing, as the branch taken at g = 0 (e.g.
    sign(0) = 0) is not the one that follows.
    """

    def __init__(self, ode, functions, directions, switches=0, periodic=()):
        exprs = [_numeric(g, ode) for g in functions]
        used = sorted(set().union(*(e.free_symbols for e in exprs)) & set(ode.states),
                      key=ode.index)
        unknown = set().union(*(e.free_symbols for e in exprs)) - set(used) - {time_symbol}
        if unknown:
            raise ValueError(f"unknown symbol {min(map(str, unknown))!r} in an event or "
                             "switch: events are functions of the states and dn.t")
        self.components = [ode.index(s) for s in used]
        self._g = [sp.lambdify([time_symbol, *used], e, "numpy") for e in exprs]
        #: rows whose function is sin(pi g) of the g given (:func:`_sin_pi`): a floor(g)
        self.periodic = np.zeros(len(exprs), dtype=bool)
        self.periodic[list(periodic)] = True
        self.affine = [None if p else _affine(e, ode) for e, p in zip(exprs, self.periodic)]
        self.directions = np.array(directions)
        self.last = np.zeros(len(exprs))
        self.from_zero = np.arange(len(exprs)) >= len(exprs) - switches

    def values(self, times, U, rows=None, levels=False):
        """g_j at the times, U the solution there (N, M): shape (n_g, M), or (len(rows), M)
        for the functions ``rows`` alone; ``levels``: the g given of a periodic row, not
        sin(pi g)."""
        args = [U[i] for i in self.components]
        rows = range(len(self._g)) if rows is None else rows
        out = np.empty((len(rows), times.size))
        for j, row in zip(rows, out):
            row[:] = self._g[j](times, *args)  # (broadcast: a constant g gives a number)
            if self.periodic[j] and not levels:
                row[:] = _sin_pi(row)
        return out

    def start(self, t, u):
        self.last = np.sign(self.values(np.array([t]), u[:, None])[:, 0])

    def brackets(self, begin, times, U):
        """(a, b, j, sign after) of every crossing seen at the sample ``times`` (sorted, after
        ``begin``; U the solution there): g_j changes sign in [a, b]; updates ``last``."""
        G = self.values(times, U)
        a, b, which, after = [np.empty(0)], [np.empty(0)], [np.empty(0, int)], [np.empty(0)]
        for j in range(G.shape[0]):
            s = np.sign(G[j])
            before = np.concatenate([[self.last[j]], s])
            index = np.where(before != 0, np.arange(before.size), 0)
            previous = before[np.maximum.accumulate(index)]  # last nonzero sign so far
            leaves_zero = self.from_zero[j] & (previous[:-1] == 0)
            hits = np.flatnonzero((s != 0) & ((s == -previous[:-1]) | leaves_zero))
            hits = hits[self.directions[j] * s[hits] >= 0]
            a.append(np.where(hits > 0, times[hits - 1], begin))
            b.append(times[hits])
            which.append(np.full(hits.size, j))
            after.append(s[hits])
            nonzero = np.flatnonzero(s)
            if nonzero.size:
                self.last[j] = s[nonzero[-1]]
        return tuple(np.concatenate(x) for x in (a, b, which, after))

    def roots(self, sol, a, b, which):
        """The crossings of g_which[r] in [a_r, b_r] on the polynomials, to _ROOT_RTOL, by the
        Illinois method (regula falsi, the end kept twice has its value halved) on all
        brackets at once; a_r where g is zero there (a crossing on a node, as at a
        breakpoint); NaN where g does not change sign there."""
        roots = np.full(a.size, np.nan)
        if a.size == 0:
            return roots
        ga, gb = self._at(sol, a, which), self._at(sol, b, which)
        # at a restart on the switch just crossed, g(a) is zero or rounding's sign (3u =
        # 101 to 1 ulp, before 3u = 102 in the same bracket); where g is on the side it came
        # from just after a, the crossing is inside, searched from there
        near = np.flatnonzero((ga == 0) | (np.sign(ga) == np.sign(gb)))
        if near.size:
            nudged = a[near] + _ROOT_RTOL * np.maximum(abs(a[near]), abs(b[near]))
            g_after = self._at(sol, nudged, which[near])
            inside = (np.sign(g_after) == -np.sign(gb[near])) & (nudged < b[near])
            a, ga = a.copy(), ga.copy()
            a[near[inside]], ga[near[inside]] = nudged[inside], g_after[inside]
        roots[ga == 0] = a[ga == 0]
        live = np.flatnonzero((ga != 0) & (np.sign(ga) != np.sign(gb)))
        lo, hi, glo, ghi, rows = a[live], b[live], ga[live], gb[live], which[live]
        side = np.zeros(live.size)
        for _ in range(_ROOT_ITERATIONS):
            i = np.flatnonzero(hi - lo > _ROOT_RTOL * np.maximum(abs(lo), abs(hi)) + 1e-300)
            if i.size == 0:
                break
            m = (lo[i] * ghi[i] - hi[i] * glo[i]) / (ghi[i] - glo[i])
            m = np.where(np.isfinite(m) & (m > lo[i]) & (m < hi[i]), m, 0.5 * (lo[i] + hi[i]))
            gm = self._at(sol, m, rows[i])
            right = np.sign(gm) == np.sign(glo[i])  # the crossing is in [m, hi]
            ghi[i] = np.where(right & (side[i] == 1), 0.5 * ghi[i], ghi[i])
            glo[i] = np.where(~right & (side[i] == -1), 0.5 * glo[i], glo[i])
            lo[i], glo[i] = np.where(right, m, lo[i]), np.where(right, gm, glo[i])
            hi[i], ghi[i] = np.where(right, hi[i], m), np.where(right, ghi[i], gm)
            side[i] = np.where(right, 1, -1)
            lo[i] = np.where(gm == 0, m, lo[i])  # a zero on a node: done
        roots[live] = hi
        return roots

    def _at(self, sol, t, rows):
        """g_rows[r] at t_r on the solution."""
        return self.values(t, sol._galerkin(t))[rows, np.arange(t.size)]


@dataclass
class Plan:
    """What a solve with discontinuities or events needs: the switches of f (in the order of
    their parameters after the ODE's own), the breakpoints, the user's events, and one
    :class:`Detector` for the events followed by the switches on the state."""

    switches: list
    breakpoints: np.ndarray
    events: list
    state_switches: list
    detector: Detector
    t_switches: Detector

    features: Features
    #: Whether f has jumps or there are events or given breakpoints (else the plan only
    #: splits a smooth f around its narrow features).
    watched: bool = True

    @classmethod
    def make(cls, ode, switches, given_breakpoints, events):
        """The plan of a solve, or None when there is nothing to watch (the plain loop)."""
        features = narrow_features(ode)
        if not (switches or events or given_breakpoints is not None or len(features)):
            return None
        events = events or []
        # made once per declaration, parameter values, interval and events (sympy's solveset
        # and lambdify would otherwise dominate a small solve)
        key = (getattr(ode, "templates", None) or ode.rhs, tuple(ode.params.values()),
               ode.t0, ode.T,
               () if given_breakpoints is None else tuple(given_breakpoints),
               tuple((e.g, e.terminal, e.direction) for e in events))
        times, on_state, detector, t_detector = ode._derived(
            "_plan", key, lambda: cls._parts(ode, switches, given_breakpoints, events))
        if not (switches or events or times.size):
            return None
        return cls(switches, times, events, on_state, detector, t_detector, features,
                   bool(switches or events or given_breakpoints is not None))

    @staticmethod
    def _parts(ode, switches, given_breakpoints, events):
        """The breakpoints, the switches on the state and the two detectors of a plan. A
        floor(g) of the state jumps where g crosses an integer: its detector watches
        sin(pi g)."""
        times = breakpoints(ode, switches, [] if given_breakpoints is None
                            else given_breakpoints, narrow_features(ode).edges())
        t_only = [s for s in switches if not (_numeric(s.g, ode).free_symbols - {time_symbol})]
        on_state = [s for s in switches if not any(s is o for o in t_only)]
        detector = Detector(ode, [e.g for e in events] + [s.g for s in on_state],
                            [e.direction for e in events] + [0] * len(on_state),
                            switches=len(on_state),
                            periodic=[len(events) + i for i, s in enumerate(on_state) if s.floor])
        return times, on_state, detector, Detector(ode, [s.g for s in t_only], [0] * len(t_only))

    terminated = False
    switched = 0  # crossings of switches on the state where f jumps
    kinked = 0  # crossings of kinks of the state (f continuous)
    end = None  # the time the solution reaches (from march)
    terminal = None  # (t, j, state) of the terminal event

    def __post_init__(self):
        self.pending = []  # brackets (a, b, j) of events to locate on the final solution
        self.located = []  # (times, j, states) of those located before a stop
        self.restarts = []  # (t, sigma) of each restart of the loop (march), in time order
        self.stops = np.array([e.terminal for e in self.events]
                              + [True] * len(self.state_switches), dtype=bool)
        # (i, sign) of the state switches on g_i = sign g_j, which cross with switch j
        # (Abs(x) and Max(x, 0), on x and -x): located once, all switched at once
        on = {}
        for i, switch in enumerate(self.state_switches):
            on.setdefault((switch.g, switch.floor), []).append(i)
        self.partners = [[(i, 1.0) for i in on[s.g, s.floor]]
                         + [(i, -1.0) for i in on.get((-s.g, s.floor), [])]
                         for s in self.state_switches]

    def solved_ode(self, ode):
        """The ODE on the interval solved: [t0, t_event] after a terminal event."""
        if not self.terminated:
            return ode
        ended = copy.copy(ode)
        ended.__dict__.pop("_compiled", None)
        ended._set_interval(ode.t0, self.end)
        return ended

    def report(self, sol):
        """Set sol.t_events, sol.y_events (per event, as solve_ivp), status and message."""
        sol.stats["breakpoints"] = self.breakpoints.size
        sol.stats["narrow features"] = len(self.features)
        sol.stats["singular points"] = len(self.features.singular)
        sol.stats["state switches"] = self.switched
        sol.stats["state kinks"] = self.kinked
        if self.switches:
            sol._set_branches(branches_taken(self.restarts))
        if self.events:
            a, b, which = (np.concatenate(x) for x in zip((np.empty(0), np.empty(0),
                                                          np.empty(0, int)), *self.pending))
            times = self.detector.roots(sol, a, b, which)
            found = ~np.isnan(times)
            located = [(times[found], which[found], sol._evaluate(times[found]).T),
                       *self.located]
            if self.terminal is not None:
                te, j, state = self.terminal
                located.append((np.array([te]), np.array([j]), state[None, :]))
            times, which, states = (np.concatenate(x) for x in zip(*located))
            order = np.argsort(times, kind="stable")
            times, which, states = times[order], which[order], states[order]
            sol.t_events = [times[which == j] for j in range(len(self.events))]
            sol.y_events = [states[which == j] for j in range(len(self.events))]
        if self.terminated:
            sol.status = TERMINATED
            sol.message = f"A termination event occurred at t = {self.end:.17g}."

    def unresolved_switch_step(self, sol):
        """A posteriori check of the switches on the state: the number of sign changes of
        each switching function g on the final solution (:meth:`_samples`) against the
        crossings located. A crossing inside an element that was not located (an element
        longer than the time g takes to come back) leaves f on the wrong branch there.
        Returns None when none was missed, else (step, where, what): a step bound for a new
        solve, a quarter of the shortest time between sign changes seen, and the time and
        crossing of that shortest gap ("g = 0", or "g at an integer" for a floor(g); None,
        None if no g changed sign twice)."""
        if not self.state_switches or not sol.dense:
            return None
        # (partners cross together and are counted once)
        distinct = [k for k, same in enumerate(self.partners) if min(same)[0] == k]
        times, G, _ = self._samples(sol, len(self.events) + np.array(distinct, dtype=int))
        changes, shortest, where, switch = 0, np.inf, None, None
        for k, g in zip(distinct, G):
            change = _changes(g)
            changes += change.size
            if change.size > 1:
                gaps = np.diff(times[change])
                if gaps.min() < shortest:
                    shortest, where = gaps.min(), float(times[change[np.argmin(gaps)]])
                    s = self.state_switches[k]
                    switch = f"{s.g} at an integer" if s.floor else f"{s.g} = 0"
        if changes <= self.switched + self.kinked:
            return None
        span = sol.ode.T - sol.ode.t0
        return min(shortest, span / max(changes, 1)) / 4, where, switch

    def check_events(self, sol, tolerance):
        """Warn (ToleranceWarning) where an event's function, sampled on the final solution
        (:meth:`_samples`), crosses zero inside an element more often than the crossing its
        ends show: events are located where g changes sign between element ends, and two
        crossings inside one element are not seen (u' = -u with the event sin(50 t): 5 of
        159 located at tolerance 1e-3). The samples include g's extremes between them
        (:func:`_extremes`): u - 0.9999 on u = sin t crosses zero and back in 0.028, between
        two samples of cG(4)'s elements at 1e-6, unseen. Samples within ``tolerance`` max
        |g| of zero do not count. The warning gives the largest excursion missed (a g that
        touches zero crosses it by the error inside an element: sin t - 1 by 3e-5 with
        dG(1) at 1e-6) and the maximum_time_step that would show the crossings: a quarter of
        the shortest time between the sign changes seen. The events :meth:`_may_hide`
        clears are not sampled."""
        if not self.events or not sol.dense:
            return
        rows = self._may_hide(sol, tolerance)
        if not rows.size:
            return
        times, G, first = self._samples(sol, rows, tolerance)
        for event, g in zip([self.events[j] for j in rows], G):
            floor = tolerance * np.max(np.abs(g))
            missed, largest = _hidden_crossings(g, floor, first)
            if not missed:
                continue
            gaps = np.diff(times[_changes(g, floor=floor)])
            bound = (gaps.min() if gaps.size else (sol.ode.T - sol.ode.t0) / missed) / 4
            from dolfinode.solve import _warn  # (solve imports this module)

            _warn(f"the event {event.g} crosses zero and back inside {missed} elements (its "
                  f"values at {SWITCH_SAMPLES} points in each and at its extremes between "
                  f"them, by up to {largest:.3g} where g ranges over "
                  f"{np.ptp(g):.3g}), where the crossings were not located: events are "
                  "located where g changes sign between element ends; give "
                  f"maximum_time_step={bound:.3g} (a quarter of the shortest time between the "
                  "sign changes seen)")

    def _may_hide(self, sol, tolerance):
        """The events whose samples in :meth:`check_events` may show them crossing zero and
        back inside an element: all but those a bound on the samples clears
        (:func:`_may_hide_crossings`: for a g affine in the states and free of t on a
        mono-adaptive solution in memory, from the element values alone)."""
        every = np.arange(len(self.events))
        affine = [j for j in every if self.detector.affine[j] is not None]
        if (not affine or sol.multi or type(sol) is not Solution
                or "_restarts" in sol.__dict__):
            return every
        # the check's sample times at the element ends (:meth:`_samples`, fraction 0)
        ends = np.unique(np.concatenate([[sol.ode.t0], sol.t_start + sol.k]))
        # (each element starts where the one before ends, to rounding: the samples inside
        # element n are then its polynomial's)
        if ends.size != sol.k.size + 1 or np.any(
                np.abs(sol.t_start - ends[:-1]) > 4 * np.spacing(np.abs(ends[1:]))):
            return every
        method = sol.method
        dense_dg = method.family == "dG" and method.q > 0  # (P = U - [U] R, solution.py)
        inside, radau, spread = _inside(tuple(method.nodes), dense_dg)
        u0 = np.asarray(sol.ode.u0, dtype=float)
        cleared = {j for j in affine if not _may_hide_crossings(
            sol.values, ends, u0, method.left_value, inside, radau, spread,
            *self.detector.affine[j], tolerance)}
        return np.array([j for j in every if j not in cleared], dtype=int)

    def _samples(self, sol, rows, tolerance=0.0):
        """(times, G, first): the detector's functions ``rows`` on the final solution at
        SWITCH_SAMPLES points in every element of the components they read (of every
        component for functions of t alone), at the end, and at the extremes between them
        that may cross zero (:func:`_extremes`, ``tolerance`` x max |g| as its floor), in
        time order; element n's samples are first[n] to first[n + 1] (its start and end)."""
        read = self.detector.components or range(sol.ode.N)
        starts = [sol.time_steps(i if sol.multi else None) for i in (read if sol.multi else [None])]
        ends = np.unique(np.concatenate([[sol.ode.t0]] + [t + k for t, k in starts]))
        fractions = np.linspace(0.0, 1.0, SWITCH_SAMPLES + 1)[:-1]
        times = np.append((ends[:-1, None] + np.diff(ends)[:, None] * fractions).ravel(),
                          ends[-1])
        G = self.detector.values(times, sol._galerkin(times), rows)
        extra = np.unique(np.concatenate(
            [_extremes(times, g, tolerance * np.max(np.abs(g))) for g in G]))
        if extra.size:
            times = np.concatenate([times, extra])
            G = np.concatenate([G, self.detector.values(extra, sol._galerkin(extra), rows)],
                               axis=1)
            order = np.argsort(times, kind="stable")
            times, G = times[order], G[:, order]
        return times, G, np.searchsorted(times, ends)

    @property
    def truncates(self):
        """Whether a crossing can end a chunk early (a terminal event or a state switch)."""
        return bool(self.state_switches) or any(e.terminal for e in self.events)

    def initial_branches(self, sigma, u0, t0, T):
        """sigma at t0 (the state switches from g(u0, t0), the t-only ones on the first
        piece; a g at its jump takes the branch there, and the branch it leaves to once it
        leaves: :meth:`Detector.brackets`)."""
        rows = len(self.events) + np.arange(len(self.state_switches))
        g = self.detector.values(np.array([t0]), u0[:, None], rows, levels=True)[:, 0]
        for s, value in zip(self.state_switches, g):
            sigma[self.switches.index(s)] = s.value(value)
        self.branches(sigma, t0, self.breakpoints[0] if self.breakpoints.size else T)

    def branch_after(self, i, sign, t, x):
        """sigma of state switch i after it crosses at (t, x), where its detected function
        then has the sign ``sign``. For floor(g), g crosses the integer n = round(g(x, t)),
        upwards where sin(pi g) takes the sign of (-1)^n: floor(g) = n, else n - 1."""
        s = self.state_switches[i]
        if not s.floor:
            return s.value(sign)
        row = [len(self.events) + i]
        n = round(float(self.detector.values(np.array([t]), x[:, None], row, levels=True)[0, 0]))
        return float(n if sign * (-1) ** (n % 2) > 0 else n - 1)

    def branches(self, sigma, begin, end):
        """sigma on the piece (begin, end): the t-only switches from g at its midpoint, the
        state switches as they are."""
        mid = np.array([0.5 * (begin + end)])
        values = self.t_switches.values(mid, np.zeros((0, 1)))[:, 0]
        t_only = [s for s in self.switches if not any(s is o for o in self.state_switches)]
        for s, g in zip(t_only, values):
            sigma[self.switches.index(s)] = s.value(g)


#: Samples per element at which :meth:`Plan.unresolved_switch_step` checks the switches
#: (and :meth:`Plan.check_events` the events).
SWITCH_SAMPLES = 8


@njit(cache=True)
def _hidden_crossings(g, floor, first):
    """(missed, largest): the elements (samples first[n] to first[n + 1] of g, from its
    start to its end) whose samples have the same sign at both ends and a value of the
    other sign beyond ``floor`` inside, and the largest |g| of those values."""
    missed, largest = 0, 0.0
    for n in range(first.size - 1):
        start, end = first[n], first[n + 1]
        sign = np.sign(g[start])
        if not sign * np.sign(g[end]) > 0:
            continue
        inner = g[start + 1:end]
        other = inner[sign * inner < -floor]
        if other.size:
            missed += 1
            largest = max(largest, float(np.max(np.abs(other))))
    return missed, largest


@njit(cache=True)
def _vertex(t0, t1, t2, a, b, c):
    """(tv, gv): the extreme of the parabola through (t0, a), (t1, b), (t2, c), in [t0, t2],
    where b is nearer zero than a and c, of one sign (an extreme of g between samples);
    (t1, b) elsewhere."""
    s = np.sign(b)
    if not (s * a > 0 and s * c > 0 and s * b <= s * a and s * b <= s * c):
        return t1, b
    slope = (b - a) / (t1 - t0)
    curve = ((c - b) / (t2 - t1) - slope) / (t2 - t0)
    if not s * curve > 0:
        return t1, b
    tv = min(max(0.5 * (t0 + t1) - slope / (2 * curve), t0), t2)
    return tv, a + (tv - t0) * (slope + curve * (tv - t1))


@njit(cache=True)
def _near_zero(b, gv, floor):
    """Whether an extreme gv of g between samples, by the one b nearest zero, may cross it:
    it comes within max(``floor``, |b| / 2) of zero."""
    return np.sign(b) * gv < max(floor, 0.5 * abs(b))


@njit(cache=True)
def _extremes(times, g, floor):
    """The times of the extremes of g between its samples (:func:`_vertex`) that may cross
    zero (:func:`_near_zero`): a crossing and back narrower than the samples' spacing (a
    level just below a smooth maximum) shows no sample of the other sign."""
    found = np.empty(max(g.size - 2, 0))
    count = 0
    for i in range(1, g.size - 1):
        tv, gv = _vertex(times[i - 1], times[i], times[i + 1], g[i - 1], g[i], g[i + 1])
        if times[i - 1] < tv < times[i + 1] and tv != times[i] and _near_zero(g[i], gv, floor):
            found[count] = tv
            count += 1
    return found[:count]


def _affine(expr, ode):
    """(c, d) with expr = c . u + d, c of shape (N,), for an ``expr`` (parameter values
    substituted) affine in the states and free of t; None for others."""
    if time_symbol in expr.free_symbols:
        return None
    c = np.zeros(ode.N)
    for i, state in enumerate(ode.states):
        slope = sp.diff(expr, state)
        if slope.free_symbols:
            return None
        c[i] = float(slope)
    d = expr.xreplace(dict.fromkeys(ode.states, sp.Integer(0)))
    return (c, float(d)) if not d.free_symbols else None


@lru_cache(maxsize=32)
def _inside(nodes, dense_dg):
    """(inside, radau, spread) of :func:`_may_hide_crossings` for a method's ``nodes``:
    inside[r, j] = l_j at the sample fractions r / SWITCH_SAMPLES inside an element (l_j
    the Lagrange basis on the nodes), R there (the right Radau polynomial on the nodes,
    R(0) = 1, R(node) = 0; zeros unless ``dense_dg``: dG(q)'s dense value P = U - [U] R),
    and 10 x the largest sum_j |l_j(tau)| + |l_j'(tau)| + |R'(tau)| on a grid of [0, 1]
    (the rounding and the sample times' offsets that the margin covers)."""
    nodes = np.asarray(nodes, dtype=float)
    fractions = np.arange(1, SWITCH_SAMPLES) / SWITCH_SAMPLES
    tau = np.linspace(0.0, 1.0, 2001)
    basis = [np.poly1d(np.poly(np.delete(nodes, j)) / np.prod(x - np.delete(nodes, j)))
             for j, x in enumerate(nodes)]
    radau = np.poly1d(np.poly(nodes) / np.prod(-nodes)) if dense_dg else np.poly1d([0.0])
    size = sum(np.abs(b(tau)) + np.abs(b.deriv()(tau)) for b in basis) + np.abs(radau.deriv()(tau))
    inside = np.ascontiguousarray(np.array([b(fractions) for b in basis]).T)
    return inside, radau(fractions), 10.0 * float(np.max(size))


@njit(cache=True)
def _may_hide_crossings(values, ends, u0, start, inside, radau, spread, c, d, tolerance):
    """Whether the check of :meth:`Plan.check_events` may find a sample of g = c . U + d
    inside an element (the Lagrange basis there: ``inside``) of the other sign than g at
    both its ends beyond its floor (``tolerance`` x max |g| over the samples), from the
    elements' values (mono-adaptive, (M, q + 1, N); ``start``: the basis at an element's
    start): g at the ends from the last node's values (the end sample U(t_n^-) = xi_q, of
    dG(q)'s dense value too; at t0 u0 or U(t0^+)), inside from the element polynomial, with
    a margin for dG(q)'s dense value there (P = U - [U] R, [U] the jump at the element's
    start, ``radau`` = R at the samples) and for the rounding of the sample times and sums
    (``spread`` x (1e-13 + 8 eps (|t_n| + |t_n+1|) / k_n) x the size of g's terms). An end
    value within its margin of zero may be of either sign: True."""
    M, q1 = values.shape[0], values.shape[1]
    g_end, margin, jump = np.empty(M + 1), np.empty(M), np.empty(M)
    floor = 0.0
    for n in range(M):
        size, jump[n], g_end[n + 1] = abs(d), 0.0, d
        for i in range(c.size):
            if c[i] != 0.0:
                after = 0.0
                for j in range(q1):
                    size += abs(c[i] * values[n, j, i])
                    after += start[j] * values[n, j, i]
                jump[n] += abs(c[i] * (after - (values[n - 1, q1 - 1, i] if n else u0[i])))
                g_end[n + 1] += c[i] * values[n, q1 - 1, i]
        margin[n] = spread * (1e-13 + 8 * 2.2e-16 * (abs(ends[n]) + abs(ends[n + 1]))
                              / (ends[n + 1] - ends[n])) * (size + jump[n])
        floor = max(floor, abs(g_end[n + 1]) - margin[n])
    # t0's sample: u0, or U(t0^+) where dG(q)'s dense value takes the element polynomial
    g_end[0] = g_first = d
    for i in range(c.size):
        after = 0.0
        for j in range(q1):
            after += start[j] * values[0, j, i]
        g_end[0] += c[i] * u0[i]
        g_first += c[i] * after
    if not (np.sign(g_end[0] - margin[0]) == np.sign(g_end[0] + margin[0])
            == np.sign(g_first - margin[0]) == np.sign(g_first + margin[0])):
        return True
    floor = tolerance * max(floor, min(abs(g_end[0]), abs(g_first)) - margin[0])
    samples = inside.shape[0] + 2
    g = np.empty(samples)
    before = np.empty(2)  # the previous element's last inner sample and its spacing
    for n in range(M):
        sign = np.sign(g_end[n])
        if abs(g_end[n + 1]) <= margin[n] or (n and abs(g_end[n]) <= margin[n - 1]):
            return True  # (the sample's sign is not known)
        g[0], g[samples - 1] = g_end[n], g_end[n + 1]
        for r in range(inside.shape[0]):
            g[r + 1] = d
            for i in range(c.size):
                if c[i] != 0.0:
                    u = 0.0
                    for j in range(q1):
                        u += inside[r, j] * values[n, j, i]
                    g[r + 1] += c[i] * u
        # the samples' and their extremes' offsets from the values the check reads
        offset = margin[n] + jump[n] * np.max(np.abs(radau))
        h = (ends[n + 1] - ends[n]) / (samples - 1)
        if n and _near_zero(g[0], _vertex(-before[1], 0.0, h, before[0], g[0] - offset * sign,
                                          g[1])[1], floor + offset):
            return True
        before[0], before[1] = g[samples - 2], h
        if not sign * np.sign(g_end[n + 1]) > 0:
            continue
        for r in range(1, samples - 1):
            if sign * g[r] - jump[n] * abs(radau[r - 1]) - margin[n] < -floor:
                return True
            if _near_zero(g[r], _vertex(-h, 0.0, h, g[r - 1], g[r] - offset * sign,
                                        g[r + 1])[1], floor + offset):
                return True
    return False


def _changes(g, direction=0, floor=0.0):
    """Indices of the samples of g just after its sign changes (values within ``floor`` of
    zero skipped): for ``direction`` 1 (-1) only those where g becomes positive (negative)."""
    nonzero = np.flatnonzero(np.abs(g) > floor)
    after, before = np.sign(g[nonzero[1:]]), np.sign(g[nonzero[:-1]])
    keep = (after != before) & ((after == direction) if direction else True)
    return nonzero[1:][keep]
#: solve_ivp's status of a solve ended by a terminal event.
TERMINATED = 1


def march(plan, loop, t0, T):
    """Integrate piece by piece between the breakpoints, locating events and state switches.

    ``loop`` runs the compiled loop (:class:`MonoPieces` or :class:`MultiPieces`). Returns
    (status, element chunks, end): status a loop status or TERMINATED, end the time the
    solution reaches. The brackets of the events that do not stop it are left in
    ``plan.pending``, the terminal event in ``plan.terminal``.
    """
    n_events = len(plan.events)
    sigma = loop.sigma()
    plan.detector.start(t0, loop.x)
    elements, recent, sol = [], [], None
    kmax = float(loop.options["kmax"][0])

    def restart():  # (the branches recorded for the dense values: Solution._set_branches)
        plan.restarts.append((loop.t(), sigma.copy()))
        loop.restart(sigma)

    for end in [*plan.breakpoints, T]:
        plan.branches(sigma, loop.t(), end)
        loop.options["kmax"] = min(kmax, plan.features.step_bound(loop.t(), end))
        restart()
        while loop.t() < end:
            for status, chunk in loop.chunks(end):
                if status not in (loop.DONE, loop.FULL):
                    return status, elements, loop.t()
                if not any(len(part) for part in chunk):  # (multi: elements or blocks)
                    continue
                sol, *samples = loop.view(chunk)
                a, b, which, after = plan.detector.brackets(*samples)
                stop = _first_stop(plan, sol, a, b, which, after)
                # the other events are located on the final solution (in one pass, see
                # Plan.report), those whose bracket holds the stop here, before it is redone
                te = np.inf if stop is None else stop[0]
                later = plan.stops[which] | (a >= te)
                now = ~later & (b >= te)
                plan.pending.append((a[~later & ~now], b[~later & ~now], which[~later & ~now]))
                times = plan.detector.roots(sol, a[now], b[now], which[now])
                located = times <= te  # (not NaN)
                plan.located.append((times[located], which[now][located],
                                     sol._evaluate(times[located]).T))
                if stop is None:
                    elements.append(chunk)
                    continue
                j, after = stop[1:]
                status, kept, te = _integrate_to_crossing(plan, loop, chunk, sol, stop[0], j)
                elements.extend(kept)
                if status not in (loop.DONE, loop.FULL):
                    return status, elements, loop.t()
                plan.detector.start(te, loop.x)
                plan.detector.last[j] = after
                if j < n_events:
                    plan.terminal = (te, j, loop.x.copy())
                    return TERMINATED, elements, te
                switch = plan.state_switches[j - n_events]
                same = plan.partners[j - n_events]
                for i, sign in same:
                    s = plan.state_switches[i]
                    sigma[plan.switches.index(s)] = plan.branch_after(i, sign * after, te, loop.x)
                    plan.detector.last[n_events + i] = sign * after
                if all(plan.state_switches[i].kink for i, _ in same):
                    plan.kinked += 1
                else:
                    plan.switched += 1
                    _check_sliding(recent, te, switch, t0, T)
                restart()
                break
    at_end = _events_at_end(plan, sol, T, loop)
    if at_end is not None:
        return TERMINATED, elements, T
    return loop.DONE, elements, T


def _events_at_end(plan, sol, T, loop):
    """Record the events whose function reaches zero at T, as solve_ivp does (a zero at
    t0 is not an event, one at T is): g_j(U(T), T) = 0, or within the location accuracy
    of zero, |g_j| <= |dg_j/dt| loop.located(T), moving towards it from the last nonzero
    sign (in the event's direction). The rounding of U(T) decides the sign of such a g, so
    without the tolerance u' = 1 with the event u - 2 at T = 2 would depend on the last
    ulp. Returns the terminal event's index (then ``plan.terminal`` is set), else None."""
    n_events = len(plan.events)
    if not n_events:
        return None
    g = plan.detector.values(np.array([T]), loop.x[:, None])[:n_events, 0]
    last = plan.detector.last[:n_events]
    approach = -last  # the sign of dg/dt of a g that reaches zero from ``last``
    ends = np.flatnonzero((last != 0) & (np.sign(g) != approach)
                          & (plan.detector.directions[:n_events] * approach >= 0))
    hit = []
    for j in ends:
        slope = np.nan if sol is None else _slope(plan.detector, sol, T, j)
        if g[j] == 0 or (np.sign(slope) == approach[j]
                         and abs(g[j]) <= abs(slope) * loop.located(T)):
            hit.append(j)
    terminal = [j for j in hit if plan.stops[j]]
    located = [j for j in hit if not plan.stops[j]]
    plan.located.append((np.full(len(located), float(T)), np.array(located, dtype=int),
                         np.tile(loop.x, (len(located), 1))))
    if not terminal:
        return None
    plan.terminal = (float(T), terminal[0], loop.x.copy())
    return terminal[0]


#: Most corrections of a crossing's time by the end value of g after the element was
#: re-integrated to end there (:func:`_integrate_to_crossing`).
_CROSSING_CORRECTIONS = 4


def _integrate_to_crossing(plan, loop, chunk, sol, te, j):
    """Re-integrate ``chunk`` up to the crossing of g_j located at ``te`` on its polynomials,
    and correct te until g_j vanishes at the new element's end: (status, element chunks,
    te), the loop at te.

    Inside an element the Galerkin polynomial is one order per degree less accurate than at
    its end, so a crossing located there is off by its error over |dg/dt|, and the branch
    switched at the wrong time leaves that error times the jump in f (dG(2) at 1e-8 on
    u'' = -sign(u) - u'/10: 1000 x the tolerance at T). At the new end, a superconvergent
    node, g is known to the tolerance; the secant method on t -> g(U(t)), started with
    dg/dt of the polynomial at te, moves te to its root."""
    saved = loop.saved  # (truncate restarts from it; the chunks below overwrite it)
    previous, slope = None, _slope(plan.detector, sol, te, j)
    for attempt in range(_CROSSING_CORRECTIONS + 1):
        loop.saved = saved
        kept, te = loop.truncate(chunk, te)
        parts = [kept]
        for status, rest in loop.chunks(te):
            if status not in (loop.DONE, loop.FULL):
                return status, parts, te
            parts.append(rest)
        g = plan.detector.values(np.array([te]), loop.x[:, None])[j, 0]
        if previous is not None and previous[1] != g:
            slope = (g - previous[1]) / (te - previous[0])
        if not np.isfinite(slope) or slope == 0:
            break
        step = g / slope
        if abs(step) <= loop.located(te) or attempt == _CROSSING_CORRECTIONS:
            break  # (the loop stands at te: a last correction would not be integrated)
        previous = (te, g)
        te -= step
    return loop.DONE, parts, te


def _slope(detector, sol, te, j):
    """d/dt g_j(U(t), t) at te on the polynomials of ``sol``: a backward difference inside
    the elements that hold te (a dG polynomial jumps at their starts)."""
    holds = (sol.t_start < te) & (sol.t_start + sol.k >= te)
    if not holds.any():
        return np.nan
    h = 1e-4 * min(sol.k[holds].min(), te - sol.t_start[holds].max())
    times = np.array([te - h, te])
    g = detector.values(times, sol._galerkin(times))[j]
    return (g[1] - g[0]) / h


def _first_stop(plan, sol, a, b, which, after):
    """(time, j, sign after) of the first crossing of a terminal event or a state switch
    among the brackets, or None; a crossing right after a restart at a is at a."""
    stops = np.flatnonzero(plan.stops[which])
    if stops.size == 0:
        return None
    first = stops[a[stops] < b[stops].min()]  # those that can come first
    roots = plan.detector.roots(sol, a[first], b[first], which[first])
    roots = np.where(np.isnan(roots), a[first], roots)
    k = int(np.argmin(roots))
    return float(roots[k]), int(which[first][k]), float(after[first][k])


def _check_sliding(recent, te, switch, t0, T):
    """Raise SolverError when the last SLIDING_SWITCHES switches where f jumps came within
    SLIDING_SPAN (T - t0) of each other: a sliding mode, which switching cannot follow.
    Kinks are not checked: across one f is continuous, so neither side pushes the solution
    back, and with f Lipschitz its crossings accumulate only along an invariant g = 0, where
    both branches agree."""
    from dolfinode.errors import SolverError

    recent.append(te)
    del recent[:-SLIDING_SWITCHES]
    if len(recent) == SLIDING_SWITCHES and recent[-1] - recent[0] < SLIDING_SPAN * (T - t0):
        # the span, not the two ends: within 1e-9 of each other they print alike
        span = recent[-1] - recent[0]
        when = f"within {span:.2g} after" if span > 0 else "all at"
        raise SolverError(f"the switch on {switch.g} changes branch {SLIDING_SWITCHES} times "
                          f"{when} t = {recent[0]:.9g}: the solution slides along {switch.g} = "
                          "0, where f is discontinuous (on both sides f points towards it). "
                          "Replace the switch by a smooth one (e.g. tanh(g / eps)), or model "
                          "the sliding motion", t=te)


class _Pieces:
    """What :func:`march` needs of a compiled loop: its time, state and branch parameters,
    chunks up to a given end, a view of a chunk as a Solution, and truncation at a time.

    ``run_chunks()`` starts the loop's chunk generator (``solve._chunks``); ``p`` and
    ``n_params`` locate sigma in the kernels' parameters; ``step_guess(x, t)`` is the first
    step of a fresh start (after a jump of f the old step says nothing)."""

    from dolfinode.timeslab import DONE, FULL

    def __init__(self, ode, method, run_chunks, options, state, x, p, n_params, step_guess):
        self.ode, self.method, self.run_chunks = ode, method, run_chunks
        self.options, self.state, self.x, self.p, self.n_params = options, state, x, p, n_params
        self.step_guess = step_guess

    def t(self):
        return float(self.state["t"][0])

    def located(self, te):
        """How far past an element start a crossing counts as at the start: the accuracy
        of its location (a crossing in a dG jump is found just past it)."""
        return _ROOT_RTOL * abs(te) + smallest_step(te, self.ode.T - self.ode.t0)

    def sigma(self):
        return self.p[self.n_params:].copy()

    def chunks(self, end):
        """The loop's chunks up to ``end``, with the state at each chunk's start kept."""
        self.options["T"] = end
        run = self.run_chunks()
        while True:
            self.saved = self.save()
            try:
                status, chunk = next(run)
            except StopIteration:
                return
            yield status, chunk


class MonoPieces(_Pieces):
    def __init__(self, *args, f0, f):
        super().__init__(*args)
        self.f0, self.f = f0, f  # f(x, t) with the kernels' current parameters

    def save(self):
        return self.x.copy()

    def restart(self, sigma):
        """A fresh start at the current time with the branches sigma."""
        self.p[self.n_params:] = sigma
        self.f0[:] = self.f(self.x, self.t())
        self.state[["have_f0", "eps_prev", "k_accepted", "carried"]] = True, 1.0, 0.0, False
        if not self.options["fixed"][0]:  # (fixed steps stay the given step)
            self.state["k_next"] = min(self.state["k_next"][0], self.step_guess(self.x, self.t()))

    def view(self, chunk):
        from dolfinode.solution import Solution

        t_start, k, values = chunk
        sol = Solution(self.ode, self.method, t_start, k, values, {}, 2)
        return sol, t_start[0], t_start + k, values[:, -1, :].T

    def truncate(self, chunk, te):
        """The chunk's elements before the one containing te, and te; the loop restarts at
        its start (with U(t_n^-)), or at te when an element ends there. A te just past
        an element start (a crossing in a dG jump, see ``located``) is taken as the start."""
        t_start, k, values = chunk
        t_end = t_start + k
        n = min(int(np.searchsorted(t_end, te)), len(k) - 1)
        if self.method.family == "cG":
            left = values[n, 0]
        else:
            left = values[n - 1, -1] if n > 0 else self.saved
        if te - t_start[n] <= self.located(te):
            keep, t, te, x = n, t_start[n], t_start[n], left
        elif t_end[n] <= te:
            keep, t, te, x = n + 1, t_end[n], t_end[n], values[n, -1]
        else:
            keep, t, x = n, t_start[n], left
        self.x[:] = x
        self.state[["t", "k_next", "have_f0", "carried"]] = t, k[n], False, False
        return [a[:keep] for a in chunk], te


class MultiPieces(_Pieces):
    def __init__(self, *args, kdes, frozen, components):
        super().__init__(*args)
        self.kdes, self.frozen, self.components = kdes, frozen, components

    def save(self):
        return self.state.copy(), self.x.copy(), self.kdes.copy(), self.frozen.copy()

    def restart(self, sigma):
        self.p[self.n_params:] = sigma
        if not self.options["fixed"][0]:  # (fixed steps stay the given step)
            self.kdes[:] = np.minimum(self.kdes, self.step_guess(self.x, self.t()))
        self.state["carried"] = False  # (the loop's carried state predates the jump)

    def view(self, chunk):
        """The chunk as a Solution, the frozen components as constants since they froze."""
        from dolfinode.io.history import as_elements
        from dolfinode.solution import Solution

        comp, a, b, values = as_elements(chunk, self.ode.N)
        frozen = np.flatnonzero(~np.isnan(self.frozen))
        begin = float(self.saved[0]["t"][0])
        times = b[np.isin(comp, self.components)] if self.components else b
        times = np.unique(times[times > begin])
        comp = np.concatenate([comp, frozen])
        a = np.concatenate([a, self.frozen[frozen]])
        b = np.concatenate([b, np.full(frozen.size, self.t())])
        values = np.concatenate([values, np.repeat(self.x[frozen, None], values.shape[1], 1)])
        sol = Solution.multi_adaptive(self.ode, self.method, comp, a, b, values, {}, 2)
        return sol, begin, times, sol._galerkin(times)

    def truncate(self, chunk, te):
        """Nothing of the chunk, and te: the loop restarts at its start (a slab boundary,
        where all components meet), which is te when te is just past it (``located``)."""
        state, x, kdes, frozen = self.saved
        self.state[:], self.x[:], self.kdes[:], self.frozen[:] = state, x, kdes, frozen
        self.state["carried"] = False  # (its carried arrays are the chunk's end's)
        if te - state["t"][0] <= self.located(te):
            te = float(state["t"][0])
        return [a[:0] for a in chunk], te
