"""Narrow features of f(t): pulses in the terms of f that depend on t alone, found before the
solve so that no step jumps over them.

A step control sees f only where it evaluates it: in u' = -u + 20 exp(-((t - 6)/0.05)^2)
on [0, 10] the pulse is zero to rounding at every point a long step evaluates, and the
solution misses it without a warning. The terms of f free of the states (a forcing, a
source, a pulse times a parameter or a state: the factor free of the states) are therefore
bounded by interval arithmetic on their sympy trees (:func:`enclose`) over pieces of
[t0, T], split until on each piece the term h is

- *slow*: its variation over the piece J at most FAST R |J| / (T - t0), R the range of h
  over [t0, T] (no faster than a function crossing its range FAST times over the interval),
- or *resolved*: its variation at most RESOLVED R,

down to MIN_WIDTH (T - t0). The pieces that are not slow, joined across gaps shorter than
themselves, are the fast stretches of h; each, widened by its own width on both sides
(where a Gaussian has fallen to e^-30 of its peak), is a feature [a, b]: the solve gets
breakpoints at a and b (a fresh first step at a) and a largest step of (fast width) /
STEPS_ACROSS inside it.

Guaranteed, up to the rounding of the bounds: every stretch of [t0, T] at least MIN_WIDTH
(T - t0) long on which a smooth state-free term changes faster than FAST R / (T - t0) lies in
a feature, unless the fast stretches of that term cover more than SPREAD of [t0, T], or are
more than MAX_FEATURES (a ToleranceWarning says so and names the term), or the term holds a
function :func:`enclose` cannot bound (it is then listed in ``unbounded``).

*Oscillations*: a term fast over more than SPREAD of [t0, T] (forcing that varies everywhere,
as sin(omega t)) is no feature, but the step control does not see it either once a step
spans its period: it evaluates f at a few points of each step, and a step of half a period
of sin(omega t) has its end points on the zeros. u' = -u + sin(1e4 t) on [0, 2] took steps
of 2-70 periods and ended 19-78,000 x the tolerance off (cG(1..2), dG(1..2), mcG(2); one
run unwarned); with steps of a quarter period at most, 0.0002-1.7 x. Such a term h bounds
every step by ``OSCILLATION_STEP`` R / max |h'| (R its range over [t0, T], |h'| bounded by
the pieces' variations: 1 / omega for sin(omega t), period / 6.3), unless its effect
R (T - t0) is below every absolute tolerance (:meth:`Features.step_cap`). Terms with jumps (Piecewise, Heaviside, ...) are split at
their breakpoints instead (:mod:`dolfinode.events`) and searched for singular points only.

*Singular points*: where a derivative of order at most SINGULAR_ORDER of a state-free term
is unbounded (|t - s|^(1/2), ((t - s)^2)^(1/3), the kink of |t - s|^(3/2)), a step ending
at s is far from a polynomial there and the step control, which estimates the error from
the polynomial, accepts it: u' = sqrt(1 - t) on [0, 1], dG(2) at 1e-8, was 261 x the
tolerance at T. Around each such point s the steps are graded: rings [s + r/2, s + r] on
both sides, r halving from span / RINGS_FROM down to MIN_WIDTH (T - t0), each a feature
with largest step GRADING r / 2, so that no step is longer than GRADING times its distance
to s, as the steps growing from t0 are near a singular t0 (sqrt(t) from 0 is within the
tolerance). Jumps of the derivatives (DiracDelta) are breakpoints, not singular points.
"""
import functools
import itertools
from dataclasses import dataclass

import numpy as np
import sympy as sp
from scipy import special

from dolfinode.compile.codegen import absorb_coefficient
from dolfinode.ode import t as time_symbol

#: A term is fast on a piece J where it varies by more than FAST R |J| / (T - t0).
FAST = 16.0
#: ... and resolved where it varies by at most RESOLVED R: then it is not split further.
RESOLVED = 0.1
#: Pieces are not split below MIN_WIDTH (T - t0) (features down to ~10 x that are found).
MIN_WIDTH = 1e-8
#: Equal pieces the search starts from.
GRID = 64
#: Most piece bounds per term: a term that needs more varies everywhere (no feature).
BUDGET = 2**15
#: Fast stretches covering more than SPREAD (T - t0), or more than MAX_FEATURES of them:
#: forcing that varies everywhere, which the step control sees at every step.
SPREAD = 0.25
MAX_FEATURES = 64
#: Largest step inside a feature: its fast width / STEPS_ACROSS.
STEPS_ACROSS = 8
#: Largest step under a term fast everywhere: OSCILLATION_STEP x the time it takes to cross
#: its range at its fastest (1 / omega for sin(omega t): a sixth of the period).
OSCILLATION_STEP = 0.5
#: Derivatives of a term searched for singular points (|t - s|^p with p < SINGULAR_ORDER).
SINGULAR_ORDER = 3
#: Near a singular point s the steps are at most GRADING |t - s| ...
GRADING = 0.25
#: ... from (T - t0) / RINGS_FROM of s inwards.
RINGS_FROM = 16


@dataclass
class Features:
    """The narrow features of an ODE's state-free terms on [t0, T]: feature j is
    [start[j], end[j]] with largest step ``step[j]``; ``unbounded``: terms that
    :func:`enclose` cannot bound (not searched)."""

    start: np.ndarray
    end: np.ndarray
    step: np.ndarray
    unbounded: list
    #: The singular points (module docstring), whose rings are among the features.
    singular: tuple = ()
    #: (largest step, range R) per term fast everywhere (module docstring, Oscillations).
    oscillations: tuple = ()

    def __len__(self):
        return self.start.size

    def edges(self):
        """The breakpoints of the features (their ends inside the interval)."""
        return np.concatenate([self.start, self.end])

    def step_cap(self, atol, span):
        """The largest step of the whole interval the oscillating terms allow: inf
        without any, or where each one's effect R span is below every absolute tolerance
        ``atol`` (a forcing of amplitude 1e-12 need not be resolved at atol 1e-6)."""
        return min((step for step, R in self.oscillations if R * span > np.min(atol)),
                   default=np.inf)

    def step_bound(self, begin, end):
        """The largest step on the piece (begin, end): inf outside every feature."""
        mid = 0.5 * (begin + end)
        inside = (self.start <= mid) & (mid <= self.end)
        return float(np.min(self.step[inside], initial=np.inf))


#: No features.
NONE = Features(np.empty(0), np.empty(0), np.empty(0), [])


def narrow_features(ode):
    """The :class:`Features` of ``ode`` on [t0, T], kept on the declaration while its
    right-hand sides, interval and the values of the parameters in its state-free terms are
    unchanged (a new parameter value in ``Solver.solve(params=...)`` searches anew)."""
    if ode.autonomous:
        return NONE
    templates = getattr(ode, "templates", None)
    if templates is None:
        declared = ode.rhs
        terms, used = ode._derived("_t_terms", declared,
                                   lambda: _t_terms(ode.rhs, set(ode.states)))
    else:  # the terms of each template, whose cells' parameters vary as its slots do
        declared = templates
        terms, used = ode._derived("_t_terms", declared, lambda: _t_terms(
            [term for template in templates for _, term in template.terms],
            set().union(*(set(p.slots) | set(p.params) for p in templates))))
    key = (declared, ode.t0, ode.T, tuple(ode.params[s] for s in used))
    return ode._derived("_features", key, lambda: _search(terms, ode.params, ode.t0, ode.T))


def _t_terms(expressions, states):
    """(terms, parameters in them): the largest sub-expressions of the right-hand sides
    ``expressions`` that depend on t and not on the ``states``, sums taken term by term."""
    seen, terms = {}, set()

    def depends(expr):
        """(on t, on a state) of expr, the largest state-free terms in t under it collected
        (each node once: a traversal linear in the size of f)."""
        if expr in seen:
            return seen[expr]
        if expr.is_Symbol:
            seen[expr] = (expr == time_symbol, expr in states)
            return seen[expr]
        below = [depends(arg) for arg in expr.args]
        on_t, on_state = any(b[0] for b in below), any(b[1] for b in below)
        seen[expr] = on_t, on_state
        if on_state:
            for arg, (arg_t, arg_state) in zip(expr.args, below):
                if arg_t and not arg_state and isinstance(arg, sp.Expr):
                    terms.update(h for h in sp.Add.make_args(arg) if h.has(time_symbol))
        return on_t, on_state

    for expr in expressions:
        on_t, on_state = depends(expr)
        if on_t and not on_state:
            terms.update(h for h in sp.Add.make_args(expr) if h.has(time_symbol))
    terms = sorted(terms, key=sp.default_sort_key)
    return terms, sorted(set().union(*(h.free_symbols for h in terms)) - {time_symbol}, key=str)


def _search(terms, params, t0, T):
    """:func:`narrow_features` of the ``terms`` with the parameter values ``params``."""
    from dolfinode.events import NON_SMOOTH

    found, unbounded, singular, oscillations = [], [], [], []
    for h in terms:
        with np.errstate(all="ignore"):
            singular += _singular_points(h, t0, T, dict(params.items()))
        if h.has(*NON_SMOOTH, sp.Rel):
            continue  # (its jumps are breakpoints)
        try:
            with np.errstate(all="ignore"):
                found += _features(h, t0, T, dict(params.items()))
        except Oscillating as oscillating:
            oscillations.append(oscillating.args)
        except Unbounded:
            unbounded.append(h)
        except Crowded as crowded:
            from dolfinode.solve import _warn  # (solve imports this module)

            count, width = crowded.args
            _warn(f"the term {h} of f has {count} narrow features (pulses) on "
                  f"[{t0:.6g}, {T:.6g}]: too many to split the solve at, so steps may jump "
                  f"over them; give maximum_time_step below their width (the narrowest fast "
                  f"stretch is {width:.3g} long)")
    singular = _joined(singular, MIN_WIDTH * (T - t0))
    found += [ring for s in singular for ring in _rings(s, t0, T)]
    start, end, step = np.array(sorted(found), dtype=float).reshape(-1, 3).T.copy()
    # overlapping features (of different terms) as one, with the smaller step (rings touch)
    keep = np.ones(start.size, dtype=bool)
    for j in range(1, start.size):
        i = np.flatnonzero(keep[:j])[-1]
        if start[j] < end[i]:
            end[i], step[i], keep[j] = max(end[i], end[j]), min(step[i], step[j]), False
    return Features(start[keep], end[keep], step[keep], unbounded, tuple(singular),
                    tuple(oscillations))


def _singular_points(h, t0, T, values):
    """The points of [t0, T] where a derivative of h of order 1..SINGULAR_ORDER is unbounded:
    the pieces on which :func:`enclose` bounds it by +-inf (or cannot), halved down to
    MIN_WIDTH (T - t0), their midpoints. Terms :func:`enclose` cannot bound, or whose
    derivative is unbounded on more than BUDGET pieces (a bound that is not tight), give
    none."""
    if not _may_be_singular(h):
        return []
    span = T - t0
    grid = np.linspace(t0, T, GRID + 1)
    points = []
    for d in _derivatives(h):
        left, right, evaluated = grid[:-1], grid[1:], 0
        while left.size:
            evaluated += left.size
            if evaluated > BUDGET:
                return []
            try:
                lo, hi = _enclose(d, left, right, values)
            except Unbounded:
                return []
            unbounded = ~(np.isfinite(lo) & np.isfinite(hi))
            small = right - left <= MIN_WIDTH * span
            points += list(0.5 * (left + right)[unbounded & small])
            split = unbounded & ~small
            mid = 0.5 * (left + right)
            left, right = (np.concatenate([left[split], mid[split]]),
                           np.concatenate([mid[split], right[split]]))
    near = MIN_WIDTH * span  # (a point at t0 or T is found that close to it)
    return [t0 if p - t0 <= near else T if T - p <= near else p for p in points]


#: Functions whose derivatives are bounded on bounded real intervals.
_ANALYTIC = (sp.sin, sp.cos, sp.exp, sp.sinh, sp.cosh, sp.tanh, sp.atan, sp.asinh, sp.erf,
             sp.erfc, sp.Heaviside)


def _may_be_singular(h):
    """Whether h holds a power other than a nonnegative integer one or a function not in
    _ANALYTIC (sums of sines are not searched: sympy's diff of them is the cost)."""
    return (any(not (p.exp.is_Integer and p.exp >= 0) for p in h.atoms(sp.Pow))
            or any(not isinstance(f, _ANALYTIC) for f in h.atoms(sp.Function)))


@functools.lru_cache(maxsize=1024)
def _derivatives(h):
    """The derivatives of h in t of orders 1..SINGULAR_ORDER, without their DiracDelta
    terms; kept per term (sympy's diff dominates the search, and a new parameter value
    searches again)."""
    derivatives, d = [], h
    for _ in range(SINGULAR_ORDER):
        d = sp.diff(d, time_symbol).replace(lambda e: isinstance(e, sp.DiracDelta),
                                            lambda e: sp.S.Zero)
        derivatives.append(d)
    return tuple(derivatives)


def _joined(points, gap):
    """The points, sorted, those within ``gap`` of the previous one as their mean."""
    groups = []
    for p in sorted(points):
        if groups and p - groups[-1][-1] <= gap:
            groups[-1].append(p)
        else:
            groups.append([p])
    return [float(np.mean(g)) for g in groups]


def _rings(s, t0, T):
    """[(a, b, largest step)]: the rings of the singular point s inside [t0, T] (module
    docstring), and the innermost pieces [s - r, s + r] at r = MIN_WIDTH (T - t0)."""
    span = T - t0
    inner = MIN_WIDTH * span
    radii = span / RINGS_FROM * 0.5 ** np.arange(int(np.log2(span / RINGS_FROM / inner)) + 1)
    rings = [(s + side * r, s + side * r / 2, GRADING * r / 2)
             for r in radii for side in (-1, 1)] + [(s - radii[-1] / 2, s + radii[-1] / 2,
                                                     GRADING * radii[-1] / 2)]
    return [(max(t0, min(a, b)), min(T, max(a, b)), k) for a, b, k in rings
            if max(a, b) > t0 and min(a, b) < T]


def _features(h, t0, T, values):
    """[(a, b, largest step)] of the features of one term h(t) with the parameter
    ``values`` (module docstring)."""
    span = T - t0
    grid = np.linspace(t0, T, GRID + 1)
    left, right = grid[:-1], grid[1:]
    low, high, done, evaluated = np.inf, -np.inf, [], 0
    while left.size:
        evaluated += left.size
        if evaluated > BUDGET:  # fast over most of [t0, T], or many narrow pulses
            if np.sum(right - left) > SPREAD * span:
                _oscillating(h, t0, T, values, high - low)
                return []
            raise Crowded(f"more than {MAX_FEATURES}", float(np.min(right - left)))
        lo, hi = _enclose(h, left, right, values)
        mid = 0.5 * (left + right)
        at_mid = _enclose(h, mid, mid, values)[0]
        finite = at_mid[np.isfinite(at_mid)]
        if finite.size:
            low, high = min(low, float(np.min(finite))), max(high, float(np.max(finite)))
        variation = np.where(np.isnan(hi - lo), np.inf, hi - lo)
        width = right - left
        final = ((variation <= (high - low) * np.maximum(RESOLVED, FAST * width / span))
                 | (width <= MIN_WIDTH * span))
        done.append((left[final], right[final], variation[final]))
        split = ~final
        left, right = (np.concatenate([left[split], mid[split]]),
                       np.concatenate([mid[split], right[split]]))
    left, right, variation = (np.concatenate(x) for x in zip(*done))
    order = np.argsort(left)
    left, right, variation = left[order], right[order], variation[order]
    fast = variation > (high - low) * FAST * (right - left) / span
    if not fast.any():
        return []
    stretches = _stretches(left[fast], right[fast])
    widths = np.array([b - a for a, b in stretches])
    if widths.sum() > SPREAD * span:
        _oscillating(h, t0, T, values, high - low)
        return []
    if len(stretches) > MAX_FEATURES:
        raise Crowded(str(len(stretches)), float(np.min(widths)))
    return [(max(t0, a - w), min(T, b + w), w / STEPS_ACROSS)
            for (a, b), w in zip(stretches, widths)]


def _oscillating(h, t0, T, values, R):
    """Raise Oscillating(largest step, R) for a term h fast everywhere whose range over
    [t0, T] is R: the step OSCILLATION_STEP R / max |h'|, |h'| bounded by :func:`enclose`
    on GRID pieces (the search's own pieces stop at BUDGET, short of resolving a fast sine).
    Nothing where h' has no bound."""
    grid = np.linspace(t0, T, GRID + 1)
    try:
        lo, hi = _enclose(_derivatives(h)[0], grid[:-1], grid[1:], values)
    except Unbounded:
        return
    rate = float(np.max(np.maximum(np.abs(lo), np.abs(hi))))
    if np.isfinite(rate) and rate > 0.0 and np.isfinite(R) and R > 0.0:
        raise Oscillating(OSCILLATION_STEP * R / rate, R)


def _stretches(left, right):
    """The pieces [left_i, right_i] (sorted) joined where they touch, then across gaps
    shorter than the wider of the two neighbouring runs of pieces: [(a, b)]."""
    joined = [[left[0], right[0]]]
    for a, b in zip(left[1:], right[1:]):
        if a <= joined[-1][1]:
            joined[-1][1] = b
        else:
            joined.append([a, b])
    merged = [list(joined[0])]
    for (c, d), (a, b) in itertools.pairwise(joined):
        # (the neighbours' own widths: a merged stretch growing would join a whole train)
        if a - d < max(d - c, b - a):
            merged[-1][1] = b
        else:
            merged.append([a, b])
    return [tuple(s) for s in merged]


class Unbounded(ValueError):
    """A function :func:`enclose` has no bounds for."""


class Oscillating(ValueError):
    """A term fast everywhere (not a feature): (largest step, its range R)."""


class Crowded(ValueError):
    """A term with more than MAX_FEATURES narrow features: (how many, the narrowest
    width)."""


def enclose(expr, lo, hi, values=None):
    """Bounds (low, high) of expr(t) for t in [lo_i, hi_i] (arrays), by interval arithmetic
    on the sympy tree: sums and products of the bounds of the arguments, powers, and the
    monotone or periodic elementary functions (exp, log, sin, cos, tan, cosh, Abs, Min, Max,
    Heaviside and the monotone ones: sinh, tanh, asin, acos, atan, asinh, acosh, atanh, erf,
    erfc, sign). The bounds hold for every t in the piece (up to rounding) and are tight as the
    piece shrinks, except where the same subexpression enters twice (t - t). ``values``:
    the values of the other symbols (parameters).

    Raises
    ------
    Unbounded
        For a function it has no bounds for.
    """
    with np.errstate(all="ignore"):
        return _enclose(expr, lo, hi, values or {})


def _enclose(e, lo, hi, values):
    if e.is_Symbol:  # (t by value: a cleared sympy cache makes a second t object)
        if e == time_symbol:
            return lo, hi
        if e not in values:
            raise Unbounded(f"no value for {e}")
        value = np.full(lo.shape, values[e])
        return value, value
    if e.is_Number or isinstance(e, sp.NumberSymbol):  # (pi, E)
        value = np.full(lo.shape, float(e))
        return value, value
    if e.is_Add:
        bounds = [_enclose(a, lo, hi, values) for a in e.args]
        return sum(b[0] for b in bounds), sum(b[1] for b in bounds)
    if e.is_Mul:
        absorbed = absorb_coefficient(e, sp.Float)
        if absorbed is not e:
            return _enclose(absorbed, lo, hi, values)
        a, b = _enclose(e.args[0], lo, hi, values)
        for arg in e.args[1:]:
            c, d = _enclose(arg, lo, hi, values)
            # (fmin, fmax: a product 0 x inf, NaN, is left out; a factor that is 0 on the
            # whole piece, Heaviside(sin t) where sin t < 0, makes the product 0 there)
            zero = ((a == 0) & (b == 0)) | ((c == 0) & (d == 0))
            ac, ad, bc, bd = a * c, a * d, b * c, b * d
            a, b = (np.where(zero, 0.0, np.fmin(np.fmin(ac, ad), np.fmin(bc, bd))),
                    np.where(zero, 0.0, np.fmax(np.fmax(ac, ad), np.fmax(bc, bd))))
        return a, b
    if e.is_Pow:
        return _power(e, lo, hi, values)
    if isinstance(e, sp.exp):
        a, b = _enclose(e.args[0], lo, hi, values)
        return np.exp(a), np.exp(b)
    if isinstance(e, sp.log):
        a, b = _enclose(e.args[0], lo, hi, values)
        return np.where(a > 0, np.log(a), -np.inf), np.log(b)
    if isinstance(e, (sp.sin, sp.cos)):
        a, b = _enclose(e.args[0], lo, hi, values)
        shift = 0.5 * np.pi if isinstance(e, sp.cos) else 0.0
        return _sine(a + shift, b + shift)
    if type(e) in _INCREASING:
        a, b = _enclose(e.args[0], lo, hi, values)
        return _INCREASING[type(e)](a), _INCREASING[type(e)](b)
    if type(e) in _DECREASING:
        a, b = _enclose(e.args[0], lo, hi, values)
        return _DECREASING[type(e)](b), _DECREASING[type(e)](a)
    if isinstance(e, sp.tan):
        a, b = _enclose(e.args[0], lo, hi, values)
        pole = np.ceil((a - 0.5 * np.pi) / np.pi) * np.pi + 0.5 * np.pi <= b
        return np.where(pole, -np.inf, np.tan(a)), np.where(pole, np.inf, np.tan(b))
    if isinstance(e, (sp.cosh, sp.Abs)):
        a, b = _enclose(e.args[0], lo, hi, values)
        small = np.where((a <= 0) & (b >= 0), 0.0, np.minimum(abs(a), abs(b)))
        even = np.cosh if isinstance(e, sp.cosh) else np.abs
        return even(small), even(np.maximum(abs(a), abs(b)))
    if isinstance(e, sp.Heaviside):  # (any value in [0, 1] at 0)
        a, b = _enclose(e.args[0], lo, hi, values)
        return np.where(a > 0, 1.0, 0.0), np.where(b < 0, 0.0, 1.0)
    if isinstance(e, (sp.Min, sp.Max)):
        bounds = [_enclose(a, lo, hi, values) for a in e.args]
        pick = np.minimum if isinstance(e, sp.Min) else np.maximum
        return (functools.reduce(pick, [b[0] for b in bounds]),
                functools.reduce(pick, [b[1] for b in bounds]))
    raise Unbounded(f"no interval bounds for {type(e).__name__}")


_INCREASING = {sp.tanh: np.tanh, sp.atan: np.arctan, sp.sinh: np.sinh, sp.asinh: np.arcsinh,
               sp.asin: np.arcsin, sp.atanh: np.arctanh, sp.acosh: np.arccosh,
               sp.erf: special.erf, sp.sign: np.sign}
_DECREASING = {sp.erfc: special.erfc, sp.acos: np.arccos}


def _power(e, lo, hi, values):
    """Bounds of base^exponent: integer exponents of any base, others of a positive base."""
    base, exponent = e.args
    if not exponent.is_Number:
        return _enclose(sp.exp(exponent * sp.log(base)), lo, hi, values)
    a, b = _enclose(base, lo, hi, values)
    p = float(exponent)
    if exponent.is_Integer and p > 0:
        if int(p) % 2:
            return a**p, b**p
        small = np.where((a <= 0) & (b >= 0), 0.0, np.minimum(abs(a), abs(b)))
        return small**p, np.maximum(abs(a), abs(b))**p
    if exponent.is_Integer:
        c, d = _power(sp.Pow(base, -exponent, evaluate=False), lo, hi, values)
        across = (c <= 0) & (d >= 0)
        return np.where(across, -np.inf, 1 / d), np.where(across, np.inf, 1 / c)
    a = np.where(a < 0, np.nan, a)  # (outside the domain: no bound)
    return (a**p, b**p) if p > 0 else (b**p, a**p)


def _sine(a, b):
    """Bounds of sin on [a, b]: the ends, and +-1 where a crest or trough lies inside."""
    low, high = np.minimum(np.sin(a), np.sin(b)), np.maximum(np.sin(a), np.sin(b))
    crest = np.ceil((a - 0.5 * np.pi) / (2 * np.pi)) * 2 * np.pi + 0.5 * np.pi <= b
    trough = np.ceil((a + 0.5 * np.pi) / (2 * np.pi)) * 2 * np.pi - 0.5 * np.pi <= b
    return np.where(trough, -1.0, low), np.where(crest, 1.0, high)
