"""Declaration of an ODE system u' = f(u, t) by symbolic sympy right-hand sides.

The declaration holds no numerics: it validates and stores the states, the right-hand
side expressions, the parameter values, the initial value and the time interval. Lowering
to compiled kernels happens in :mod:`dolfinode.compile`.
"""
import difflib
import math
from collections.abc import Mapping, MutableMapping
from functools import cached_property

import numpy as np
import sympy as sp

#: The time symbol usable in right-hand sides.
t = sp.Symbol("t", real=True)

_ALLOWED_FUNCTIONS = (
    sp.exp, sp.log, sp.sin, sp.cos, sp.tan, sp.asin, sp.acos, sp.atan, sp.atan2, sp.sinh,
    sp.cosh, sp.tanh, sp.asinh, sp.acosh, sp.atanh, sp.Abs, sp.sign, sp.Min, sp.Max,
    sp.Piecewise, sp.Heaviside, sp.erf, sp.erfc, sp.floor, sp.ceiling,
)


def _suggest(name, candidates):
    match = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.5)
    return f"; did you mean {match[0]!r}?" if match else ""


class ComplexValueError(TypeError):
    """A complex number given where dolfinode needs a real one."""


def _reject_complex(value, what):
    """Raise ComplexValueError if ``value`` (a number or an array) is complex: float() and
    astype(float) of a numpy complex drop the imaginary part with only a ComplexWarning."""
    if isinstance(value, (complex, np.complexfloating)) or getattr(
            getattr(value, "dtype", None), "kind", "") == "c":
        raise ComplexValueError(f"{what} is complex ({value!r}); dolfinode solves real systems: "
                                "write the real and imaginary parts as separate states or "
                                "parameters")


def _to_float(value, what="a value"):
    """``float(value)``, with a number too large for a double (an int such as 10**400, for
    which float raises OverflowError) read as +-inf, so that the finiteness checks report it.

    Raises
    ------
    TypeError, ValueError
        As ``float`` does for what is not a real number; ComplexValueError (a TypeError,
        naming ``what``) for a complex one.
    """
    _reject_complex(value, what)
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def _finite_real(value, what):
    """``value`` as a finite float; TypeError (or ComplexValueError) naming ``what`` for a
    value that is not a real number, ValueError for an infinite one."""
    try:
        value = _to_float(value, what)
    except ComplexValueError:
        raise
    except (TypeError, ValueError):
        raise TypeError(f"{what} must be a real number, got {value!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{what} must be finite, got {value}")
    return value


def _as_expression(expr, state):
    try:
        expr = sp.sympify(expr, strict=True)
    except (sp.SympifyError, TypeError, AttributeError):
        raise TypeError(f"the right-hand side of {state} is not a sympy expression: {expr!r}; "
                        "build it from sympy symbols and numbers") from None
    if not isinstance(expr, sp.Expr) or isinstance(expr, sp.MatrixBase):
        raise TypeError(f"the right-hand side of {state} must be a scalar sympy expression, "
                        f"got {type(expr).__name__}: {expr}")
    # a sawtooth written with Mod or frac is floor's jump, which the jump finder and C know
    expr = expr.replace(sp.Mod, lambda x, p: x - p * sp.floor(x / p)).replace(
        sp.frac, lambda x: x - sp.floor(x))
    if expr.has(sp.I, sp.zoo, sp.nan, sp.oo, sp.S.NegativeInfinity):  # one traversal
        raise ValueError(f"the right-hand side of {state} is not a finite real expression: {expr}")
    for call in expr.atoms(sp.Function, sp.Derivative, sp.Integral):
        if isinstance(call, (sp.Derivative, sp.Integral)) or not isinstance(call, _ALLOWED_FUNCTIONS):
            raise ValueError(f"the right-hand side of {state} uses {call}, which cannot be "
                             "compiled; use elementary functions of the states, parameters and dn.t")
    return expr


def _vector_by_state(values, states, what):
    """Turn a dict by state symbol (or a sequence in component order) into a float vector."""
    if (isinstance(values, np.ndarray) and values.dtype.kind in "fiu"
            and values.shape == (len(states),)):
        array = values.astype(float)  # a copy, without converting entry by entry
    else:
        array = _listed_vector(values, states, what)
    finite = np.isfinite(array)
    if not finite.all():  # (flatnonzero alone is most of a small solver call)
        bad = np.flatnonzero(~finite)
        raise ValueError(f"{what} is not finite for {states[bad[0]].name}: {array[bad[0]]}")
    return array


def _listed_vector(values, states, what):
    """The values of a dict by state symbol (or name), or of a sequence in component order,
    as floats in component order."""
    names = {s.name: s for s in states}
    if isinstance(values, Mapping):
        values = {names.get(k, k) if isinstance(k, str) else k: v for k, v in values.items()}
        known = set(states)  # hashed: ``in states`` compared one by one, quadratic in N
        unknown = [k for k in values if k not in known]
        if unknown:
            key = unknown[0]
            name = getattr(key, "name", str(key))
            raise ValueError(f"{what} has a value for {key!r}, which is not a state"
                             f"{_suggest(name, names)}; states are {', '.join(names)}")
        missing = [s.name for s in states if s not in values]
        if missing:
            raise ValueError(f"{what} is missing values for {', '.join(missing)}")
        vector = [values[s] for s in states]
    else:
        try:
            vector = list(np.asarray(values, dtype=object).ravel()) if not np.isscalar(values) else None
        except Exception:  # noqa: BLE001 - anything not array-like is reported below
            vector = None
        if vector is None or np.ndim(values) != 1:
            raise TypeError(f"{what} must be a dict by state symbol or a sequence of "
                            f"{len(states)} numbers, got {values!r}")
        if len(vector) != len(states):
            raise ValueError(f"{what} has {len(vector)} values but the system has "
                             f"{len(states)} states ({', '.join(names)})")
    try:
        return np.array([_to_float(v, what) for v in vector], dtype=float)
    except ComplexValueError:
        raise
    except (TypeError, ValueError):
        symbolic = [(s, v) for s, v in zip(states, vector) if getattr(v, "free_symbols", None)]
        if symbolic:
            state, value = symbolic[0]
            names = ", ".join(sorted(map(str, value.free_symbols)))
            raise TypeError(f"{what} for {state.name} is {value}, an expression of {names}: "
                            f"{what} holds numbers, read when the ODE is made. Substitute the "
                            "values (value.subs(params)); to vary them with a parameter, pass "
                            "both to dn.Solver(ode).solve(u0=..., params=...)") from None
        raise TypeError(f"{what} must hold real numbers, got {vector!r}") from None


def _parameter_value(symbol, value):
    """The value of parameter ``symbol`` as a checked finite float."""
    return _finite_real(value, f"parameter {symbol.name}")  # (str(symbol) prints with sympy)


def _read_only(array):
    array.flags.writeable = False
    return array


#: What the compiled kernels are built from: fixed once declared.
_FIXED = ("states", "rhs", "nonnegative")


class Parameters(MutableMapping):
    """The parameter values of an ODE, by symbol (or name): a value set here is checked as
    in the declaration and honoured by the next solve. The symbols are fixed: the compiled
    kernels read the values in their order."""

    def __init__(self, values):
        self._values = dict(values)

    def _symbol(self, key):
        if key in self._values:
            return key
        for symbol in self._values:
            if getattr(key, "name", key) == symbol.name:
                return symbol
        raise KeyError(key)

    def __getitem__(self, key):
        return self._values[self._symbol(key)]

    def __setitem__(self, key, value):
        try:
            symbol = self._symbol(key)
        except KeyError:
            names = [s.name for s in self._values]
            raise KeyError(f"{key!r} is not a parameter of this ODE"
                           f"{_suggest(str(getattr(key, 'name', key)), names)} (its parameters: "
                           f"{', '.join(names) or 'none'}); a new parameter needs a new ODE, or "
                           "assign ode.params = {...}") from None
        self._values[symbol] = _parameter_value(symbol, value)

    def __delitem__(self, key):
        raise TypeError("a parameter cannot be removed from an ODE (its right-hand sides may use "
                        "it); assign ode.params = {...} or declare a new ODE")

    def __iter__(self):
        return iter(self._values)

    def values(self):
        return self._values.values()  # (the Mapping default looks each key up again)

    def items(self):
        return self._values.items()

    def __len__(self):
        return len(self._values)

    def __repr__(self):
        return repr(self._values)


class ODE:
    """An initial value problem u' = f(u, t) on (t0, T], u(t0) = u0, declared with sympy.

    Parameters
    ----------
    rhs : dict
        State symbol -> right-hand side expression; the key order is the component order.
        A sequence of (symbol, expression) pairs is accepted too.
    u0 : dict or sequence
        Initial values, by state symbol or in component order.
    T : float
        Final time, T > t0.
    params : dict, optional
        Parameter symbol (or its name) -> value, for every other symbol in the right-hand
        sides.
    t0 : float, optional
        Initial time (default 0).
    nonnegative : bool or sequence, optional
        Components that stay >= 0 (concentrations, populations): True for all, or their
        state symbols (or names), or a boolean mask (N,). The solvers reject a time step on
        which such a component falls below -atol and retry with a smaller one (raising
        :class:`~dolfinode.SolverError` when that does not help), and set accepted values in
        [-atol, 0) to 0, as CVODE's inequality constraints. In a square root or other
        non-integer power the compiled f and its Jacobian read such a component as
        max(u_i, 0), so that they stay defined on iterates that dip below 0 (for
        per-component expressions; the template systems of :mod:`dolfinode.systems` read it
        as it is). Stored as the mask ``ode.nonnegative``.

    Raises
    ------
    TypeError, ValueError
        With a message naming the offending state, symbol or value.
    """

    def __init__(self, rhs, u0, T, params=None, t0=0.0, nonnegative=None):
        pairs = list(rhs.items()) if isinstance(rhs, Mapping) else self._pairs(rhs)
        if not pairs:
            raise ValueError("an ODE needs at least one state")
        states, names = [], set()
        for state, _ in pairs:
            if not isinstance(state, sp.Symbol):
                raise TypeError(f"states must be sympy Symbols, got {state!r} "
                                f"({type(state).__name__})")
            if state == t or state.name == t.name:
                raise ValueError(f"{state} is the time symbol and cannot be a state")
            if state.name in names:
                raise ValueError(f"duplicate state {state.name!r}: every state needs its own name")
            states.append(state)
            names.add(state.name)
        self.__dict__["states"] = tuple(states)
        self.__dict__["rhs"] = tuple(_as_expression(expr, state) for state, expr in pairs)
        self.params = params
        self._set_interval(t0, T)
        self.__dict__["nonnegative"] = _read_only(self._nonnegative_mask(nonnegative))
        self.u0 = u0

    # One rule for what a user can reach after declaring: the values (params, u0, t0, T) may
    # be set, are checked as in the declaration and are honoured by the next solve (the
    # compiled kernels read the parameter values anew each time, see
    # dolfinode.compile.lower); what the kernels are built from (states, rhs, nonnegative,
    # the parameter symbols) is fixed: a new one needs a new ODE. They are plain instance
    # attributes, read at dict speed (a solve reads them dozens of times); this method
    # checks the assignments.
    def __setattr__(self, name, value):
        if name in _FIXED:
            raise AttributeError(f"ode.{name} is fixed by the declaration (the compiled kernels "
                                 f"are built from it): declare a new dn.ODE; parameter values, "
                                 "u0, t0 and T may be set, or varied with dn.vary")
        if name == "params":
            self._set_params(value)
        elif name == "u0":
            self.__dict__["u0"] = _read_only(self._initial_vector(value))
        elif name in ("t0", "T"):
            times = {"t0": self.t0, "T": self.T, name: value}
            self._set_interval(times["t0"], times["T"])
        else:
            object.__setattr__(self, name, value)

    def _set_params(self, params):
        """``ode.params = {...}``: a :class:`Parameters` mapping of the checked values (its
        values may be changed, checked, and are honoured by the next solve)."""
        clean = self._params(params)
        before = self.__dict__.get("params")
        self.__dict__["params"] = Parameters(clean)
        if before is None or list(before) != list(clean):
            try:
                self._check_symbols()
            except (TypeError, ValueError):
                self.__dict__["params"] = before
                raise
            self.__dict__.pop("_compiled", None)  # its parameter vector has other slots

    def _set_interval(self, t0, T):
        """Set a validated finite t0 < T."""
        t0, T = _finite_real(t0, "t0"), _finite_real(T, "T")
        if not T > t0:
            raise ValueError(f"the final time T = {T} must be larger than t0 = {t0}")
        self.__dict__.update(t0=t0, T=T)

    def _derived(self, name, key, make):
        """``make()``, kept on this declaration under ``name`` while ``key`` (what it is
        derived from: right-hand sides, parameter values, ...) is unchanged."""
        cached = self.__dict__.get(name)
        if cached is None or cached[0] != key:
            cached = self.__dict__[name] = (key, make())
        return cached[1]

    def _snapshot(self):
        """This declaration as it is now, for a Solution to keep: later changes of the
        values on ``self`` do not reach it (a shallow copy with its own parameter values)."""
        snapshot = object.__new__(type(self))
        snapshot.__dict__.update(self.__dict__)
        snapshot.__dict__["params"] = Parameters(self.params.items())  # (a Mapping: slower)
        return snapshot

    def _initial_vector(self, u0):
        """u0 as a validated float vector in component order (dict by state or sequence)."""
        return self._in_domain(_vector_by_state(u0, self.states, "u0"))

    def _nonnegative_mask(self, nonnegative):
        """The ``nonnegative`` declaration as a boolean mask (N,)."""
        if nonnegative is None or isinstance(nonnegative, (bool, np.bool_)):
            return np.full(self.N, bool(nonnegative))
        if isinstance(nonnegative, np.ndarray) and nonnegative.dtype == bool:
            if nonnegative.shape != (self.N,):
                raise ValueError(f"nonnegative as a mask needs shape ({self.N},), got "
                                 f"{nonnegative.shape}")
            return nonnegative.copy()
        if isinstance(nonnegative, (str, sp.Symbol)) or not np.iterable(nonnegative):
            raise TypeError("nonnegative must be True, a sequence of states or a boolean "
                            f"mask, got {nonnegative!r}")
        mask = np.zeros(self.N, dtype=bool)
        for state in nonnegative:
            mask[self.index(state)] = True
        return mask

    @cached_property
    def _constrained(self):
        """Whether a component is declared nonnegative (fixed with the declaration)."""
        return bool(self.nonnegative.any())

    def _in_domain(self, u0):
        """u0, checked against the declared constraints."""
        if not self._constrained:
            return u0
        below = self.nonnegative & (u0 < 0)
        if below.any():
            i = np.flatnonzero(below)[0]
            raise ValueError(f"u0 of {self.states[i].name} is {u0[i]}, but {self.states[i].name} "
                             "is declared nonnegative")
        return u0

    @staticmethod
    def _pairs(rhs):
        try:
            pairs = [tuple(p) for p in rhs]
        except TypeError:
            raise TypeError("rhs must be a dict {state symbol: expression}, got "
                            f"{type(rhs).__name__}") from None
        if any(len(p) != 2 for p in pairs):
            raise TypeError("rhs as a sequence must hold (state, expression) pairs")
        return pairs

    def _params(self, params):
        params = {} if params is None else params
        if not isinstance(params, Mapping):
            raise TypeError(f"params must be a dict {{symbol: value}}, got {type(params).__name__}")
        clean = {}
        for symbol, value in params.items():
            if isinstance(symbol, str):
                symbol = self._parameter_named(symbol)
            if not isinstance(symbol, sp.Symbol):
                raise TypeError(f"parameter keys must be sympy Symbols or their names, got "
                                f"{symbol!r}")
            if self._is_state(symbol):
                raise ValueError(f"{symbol} is both a state and a parameter")
            if symbol == t:
                raise ValueError("dn.t is the time and cannot be a parameter")
            value = _parameter_value(symbol, value)
            if symbol in clean:
                raise ValueError(f"parameter {symbol} is given twice (by its symbol and by its "
                                 "name): give it once")
            clean[symbol] = value
        return clean

    def _free_symbols(self):
        """The symbols the right-hand sides use."""
        return set().union(*(expr.free_symbols for expr in self.rhs))

    def _parameter_named(self, name):
        """The symbol named ``name`` among those the right-hand sides use (a parameter key
        given by name)."""
        symbols = {s.name: s for s in self._free_symbols()
                   if not self._is_state(s) and s != t}
        if name not in symbols:
            raise ValueError(f"params has {name!r}, which no right-hand side uses"
                             f"{_suggest(name, symbols)}")
        return symbols[name]

    def _is_state(self, symbol):
        """Whether ``symbol`` is one of the state symbols (hashed: ``in`` the tuple compares
        with sympy's __eq__ one state at a time)."""
        return symbol in self._symbols

    def _check_symbols(self):
        known = set(self.states) | set(self.params) | {t}
        names = [s.name for s in known]
        for state, expr in zip(self.states, self.rhs):
            for symbol in sorted(expr.free_symbols - known, key=lambda s: s.name):
                if symbol.name == t.name:
                    hint = "; use dn.t for the time"
                elif symbol.name in names:
                    hint = (f": a different symbol named {symbol.name!r} is declared, with other "
                            "assumptions (such as positive=True); use the same Symbol in both")
                else:
                    hint = _suggest(symbol.name, names) + (
                        f" (if {symbol.name} is a parameter, give its value in params=)")
                raise ValueError(f"unknown symbol {symbol.name!r} in the right-hand side of "
                                 f"{state.name}{hint}")

    @property
    def N(self):
        """Number of components."""
        return len(self.states)

    @cached_property
    def autonomous(self):
        """Whether f does not depend on the time t explicitly (read once: a sympy traversal of
        every expression, which small multi-adaptive solves would otherwise repeat)."""
        return t not in self._free_symbols()

    @property
    def parameter_symbols(self):
        return tuple(self.params)

    @property
    def parameter_values(self):
        return np.array(list(self.params.values()), dtype=float)

    def index(self, state):
        """Component index of a state symbol (or of its name)."""
        positions = self._names if isinstance(state, str) else self._symbols
        try:
            return positions[state]
        except (KeyError, TypeError):
            raise ValueError(f"{state!r} is not a state"
                             f"{_suggest(str(state), self._names)}") from None

    @cached_property
    def _symbols(self):
        """Component index by state symbol."""
        return {s: i for i, s in enumerate(self.states)}

    @cached_property
    def _names(self):
        """Component index by state name."""
        return {s.name: i for i, s in enumerate(self.states)}

    @classmethod
    def second_order(cls, accelerations, x0, v0, T, params=None, t0=0.0, velocities=None,
                     nonnegative=None):
        """Declare x'' = a(x, x', t) as the first-order system (x, v)' = (v, a).

        Components are all positions, then all velocities. Velocity symbols default to
        ``Symbol(name + "_dot")``; pass ``velocities={x: xdot}`` to choose them (and use them
        in the accelerations); ``v0`` is keyed by positions or by their velocity symbols.
        ``nonnegative`` is as for :class:`ODE`, over all 2n components.
        """
        if not isinstance(accelerations, Mapping):
            raise TypeError("accelerations must be a dict {position symbol: expression}")
        positions = tuple(accelerations)
        for x in positions:
            if not isinstance(x, sp.Symbol):
                raise TypeError(f"states must be sympy Symbols, got {x!r} ({type(x).__name__})")
        velocities = dict(velocities or {})
        for x in velocities:
            if x not in accelerations:
                raise ValueError(f"velocities names {x!r}, which is not a position")
        vel = [velocities.get(x, sp.Symbol(f"{x.name}_dot")) for x in positions]
        rhs = list(zip(positions, vel)) + [(v, accelerations[x]) for x, v in zip(positions, vel)]
        if isinstance(v0, Mapping):  # keyed by positions, or by their velocity symbols
            position_of = {key: x for x, v in zip(positions, vel) for key in (v, v.name)}
            v0 = {position_of.get(key, key): value for key, value in v0.items()}
        u0 = np.concatenate([_vector_by_state(x0, positions, "x0"),
                             _vector_by_state(v0, positions, "v0")])
        ode = cls(rhs, u0=u0, T=T, params=params, t0=t0, nonnegative=nonnegative)
        ode.velocity_symbols = dict(zip(positions, vel))
        return ode

    def velocity(self, x):
        """The velocity symbol of position x in a system built by :meth:`second_order`."""
        try:
            return self.velocity_symbols[x]
        except (AttributeError, KeyError):
            raise ValueError(f"{x!r} is not a position of a second-order system") from None

    def __getstate__(self):
        # compiled kernels (ctypes) do not pickle: a receiving process compiles its own,
        # from its disk cache when it has one; a copy gets its own parameter values
        state = self.__dict__.copy()
        # nor do the events' caches (lambdified switching functions): remade on demand
        for derived in ("_compiled", "_smooth", "_plan"):
            state.pop(derived, None)
        state["params"] = Parameters(self.params)
        return state

    def __repr__(self):
        return f"ODE(N={self.N}, t0={self.t0}, T={self.T}, params={len(self.params)})"
