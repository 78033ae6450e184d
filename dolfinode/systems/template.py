"""Structured systems declared by templates: small symbolic pieces applied over index arrays.

A template is the ODE analogue of a finite element form assembled over cells. Its *slots*
are local state symbols (for a spring: the coordinates of its two endpoints); an integer
array maps the slots of every cell (edge, particle, ...) to global components; per-cell
parameters come from a float array. The right-hand side is the sum over templates and
cells,

    f_i(u, t) = sum_T sum_{e, s : I_T[e, s] = i} phi_{T,s}(u[I_T[e, :]], P_T[e, :], t),

so the symbolic work (and the generated code) depends on the few template expressions
phi_{T,s}, never on the number of components N.
"""
from collections.abc import Mapping, Sequence
from functools import cached_property

import numpy as np
import sympy as sp

from dolfinode.ode import ODE, _as_expression, _read_only, _reject_complex, _suggest, t


def _symbols(values, what):
    values = tuple(values)
    for s in values:
        if not isinstance(s, sp.Symbol):
            raise TypeError(f"{what} must be sympy Symbols, got {s!r} ({type(s).__name__})")
        if s == t or s.name == t.name:
            raise ValueError(f"{s} is the time symbol and cannot be one of the {what}")
    names = [s.name for s in values]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate is not None:
        raise ValueError(f"duplicate symbol {duplicate!r} in the {what}")
    return values


class Template:
    """An interaction (or per-particle term) applied over the cells of an index array.

    For every cell e and every slot s with a term, the template adds

        f[indices[e, s]] += terms[slots[s]](U_e, P_e, t),
        U_e = u[indices[e, :]],  P_e = values[e, :],

    to the right-hand side. Example, a linear spring of stiffness k between the positions
    a and b of two unit masses whose velocities are va and vb::

        a, b, va, vb, k = sp.symbols("a b va vb k")
        spring = Template(slots=(a, b, va, vb), terms={va: k * (b - a), vb: k * (a - b)},
                          indices=[[0, 1, 2, 3]], params=(k,), values=[[4.0]])

    Parameters
    ----------
    slots : sequence of sympy Symbol
        Local state symbols of one cell.
    terms : dict
        Slot symbol -> its contribution to the right-hand side of the component in that slot.
        Expressions may use the slots, the per-cell ``params``, the system's global
        parameters and ``dn.t``.
    indices : array_like of int, shape (E, len(slots))
        Global component of every slot of every cell.
    params : sequence of sympy Symbol, optional
        Per-cell parameter symbols.
    values : array_like of float, shape (E, len(params)), optional
        Their values, one row per cell.

    A template is fixed once declared: ``indices`` and ``values`` are read-only copies and
    its attributes cannot be set (the TemplateODEs built on it checked the indices against N
    and cache their pattern). For other values declare a new Template: the kernels are
    cached by expression, so it does not recompile.

    Raises
    ------
    TypeError, ValueError
        For symbols that are not sympy Symbols, terms on unknown slots, and arrays of the
        wrong shape, type or with non-finite values.
    """

    def __init__(self, slots, terms, indices, params=(), values=None):
        self.slots = _symbols(slots, "slots")
        if not self.slots:
            raise ValueError("a template needs at least one slot")
        self.params = _symbols(params, "template parameters")
        shared = set(self.slots) & set(self.params)
        if shared:
            raise ValueError(f"{sorted(s.name for s in shared)} are both slots and parameters")
        if not isinstance(terms, Mapping) or not terms:
            raise TypeError("terms must be a non-empty dict {slot symbol: expression}")
        for slot in terms:
            if slot not in self.slots:
                name = getattr(slot, "name", str(slot))
                raise ValueError(f"the term for {slot!r} is not on a slot"
                                 f"{_suggest(name, [s.name for s in self.slots])}; slots are "
                                 f"{', '.join(s.name for s in self.slots)}")
        # terms in slot order, so that the generated code does not depend on dict order
        self.terms = tuple((s, _as_expression(terms[s], s)) for s in self.slots if s in terms)
        self.indices = self._indices(indices)
        self.values = self._values(values)

    def __setattr__(self, name, value):
        if name in self.__dict__:
            raise AttributeError(f"Template.{name} is fixed once declared (a TemplateODE checked "
                                 "and compiled it); declare a new Template instead")
        super().__setattr__(name, value)

    def __setstate__(self, state):
        self.__dict__.update(state)  # (pickle does not keep the arrays read-only)
        for array in (self.indices, self.values):
            array.flags.writeable = False

    def _indices(self, indices):
        try:
            array = np.asarray(indices)
        except Exception:  # noqa: BLE001 - reported below
            array = None
        if array is None or array.ndim != 2 or array.shape[1] != len(self.slots):
            raise ValueError(f"indices must be an integer array of shape (cells, {len(self.slots)}) "
                             f"(one column per slot), got {np.shape(indices)}")
        if array.size and not np.issubdtype(array.dtype, np.integer):
            raise TypeError(f"indices must hold integers, got dtype {array.dtype}")
        # a copy: the user's array written later would index outside [0, N) in the kernels
        return _read_only(np.array(array, dtype=np.int64, order="C"))

    def _values(self, values):
        cells = len(self.indices)
        if values is None:
            if self.params:
                raise ValueError(f"the template parameters {', '.join(s.name for s in self.params)} "
                                 "need values= (one row per cell)")
            return _read_only(np.zeros((cells, 0)))
        _reject_complex(np.asarray(values), "values")
        try:
            array = np.array(values, dtype=float)
        except (TypeError, ValueError):
            raise TypeError("values must be a float array of shape (cells, parameters)") from None
        if array.ndim == 1 and len(self.params) == 1:
            array = array[:, None]
        if array.shape != (cells, len(self.params)):
            raise ValueError(f"values must have shape ({cells}, {len(self.params)}) (one row per "
                             f"cell, one column per parameter), got {array.shape}")
        if not np.all(np.isfinite(array)):
            e, k = np.argwhere(~np.isfinite(array))[0]
            raise ValueError(f"values is not finite for {self.params[k].name} of cell {e}")
        return _read_only(np.ascontiguousarray(array))

    @property
    def cells(self):
        """Number of cells E."""
        return len(self.indices)

    def __repr__(self):
        return (f"Template(slots={len(self.slots)}, terms={len(self.terms)}, "
                f"params={len(self.params)}, cells={self.cells})")


class StateNames(Sequence):
    """State names ``prefix_i`` generated on demand (no list of N strings is stored)."""

    def __init__(self, n, prefix="u"):
        self.n, self.prefix = int(n), str(prefix)

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(self.n))]
        if not -self.n <= i < self.n:
            raise IndexError(f"state {i} out of range for {self.n} states")
        return f"{self.prefix}_{i % self.n}"

    def __contains__(self, name):
        # parsed, not searched: Sequence's default would build the N names
        head, _, number = str(name).rpartition("_")
        return head == self.prefix and spells_index(number, self.n)


def spells_index(text, n):
    """Whether ``text`` is f"{i}" for an integer 0 <= i < n."""
    return text.isascii() and text.isdigit() and str(int(text)) == text and int(text) < n


class TemplateODE(ODE):
    """An ODE u' = f(u, t) whose right-hand side is a sum of :class:`Template` s.

    It has the interface of :class:`~dolfinode.ODE` (``N``, ``states``, ``u0``, ``T``,
    ``params``, ``index``) and is solved, differentiated and compiled the same way; the
    kernels are generated once per set of template expressions, whatever N, and read the
    index and value arrays at run time.

    Parameters
    ----------
    templates : sequence of Template
    u0 : array_like or dict
        Initial values in component order (this also gives N), or a dict by state symbol
        (then ``names`` gives N).
    T : float
        Final time, T > t0.
    params : dict, optional
        Global parameter symbol -> value, shared by all cells.
    t0 : float, optional
    names : sequence of str, optional
        State names in component order (default ``u_0, u_1, ...``); a list or tuple is
        checked for duplicates, a lazy ``Sequence`` (as :class:`StateNames`) is trusted.
        States are sympy symbols created on first use of :attr:`states`.
    nonnegative : bool or sequence, optional
        As :class:`~dolfinode.ODE`: True, state symbols or names, or a boolean mask (N,).

    Raises
    ------
    TypeError, ValueError
        As :class:`~dolfinode.ODE`, plus indices outside [0, N) and unknown symbols in a
        template (named with the template and slot).
    """

    def __init__(self, templates, u0, T, params=None, t0=0.0, names=None, nonnegative=None):
        if isinstance(templates, Template):
            templates = [templates]
        self.templates = tuple(templates)
        if not self.templates or not all(isinstance(p, Template) for p in self.templates):
            raise TypeError("templates must be a non-empty sequence of dn.Template")
        if names is None:
            if isinstance(u0, Mapping):
                raise ValueError("with u0 given as a dict, pass names= to fix the components")
            names = StateNames(np.size(u0))
        elif isinstance(names, (list, tuple)) or not isinstance(names, Sequence):
            # a lazy Sequence (StateNames, ParticleNames) is trusted to be unique: checking
            # it would build the N strings it exists to avoid
            names = tuple(str(n) for n in names)
            if len(set(names)) != len(names):
                raise ValueError("duplicate state names: every state needs its own name")
            if t.name in names:
                raise ValueError(f"{t.name} is the time symbol and cannot be a state")
        self.names = names
        self._n = len(names)
        if self._n == 0:
            raise ValueError("an ODE needs at least one state")
        self.params = params
        self._set_interval(t0, T)
        self.__dict__["nonnegative"] = _read_only(self._nonnegative_mask(nonnegative))
        self.u0 = u0

    def _initial_vector(self, u0):
        if isinstance(u0, Mapping):
            return super()._initial_vector(u0)
        _reject_complex(np.asarray(u0), "u0")
        try:
            array = np.array(u0, dtype=float)
        except (TypeError, ValueError):
            raise TypeError("u0 must be a sequence of real numbers or a dict by state") from None
        if array.shape != (self._n,):
            raise ValueError(f"u0 has shape {array.shape} but the system has {self._n} states")
        bad = np.flatnonzero(~np.isfinite(array))
        if bad.size:
            raise ValueError(f"u0 is not finite for {self.names[bad[0]]}: {array[bad[0]]}")
        return self._in_domain(array)

    def _free_symbols(self):
        """The symbols the terms use besides their slots and cell parameters."""
        return set().union(*(expr.free_symbols for template in self.templates
                             for _, expr in template.terms)) - {
            s for template in self.templates for s in (*template.slots, *template.params)}

    def _params(self, params):
        clean = super()._params(params)
        for template in self.templates:
            for s in clean:
                if s in template.slots or s in template.params:
                    raise ValueError(f"{s} is both a global parameter and a symbol of {template}")
        return clean

    def _check_symbols(self):
        known = set(self.params) | {t}
        for number, template in enumerate(self.templates):
            local = known | set(template.slots) | set(template.params)
            names = [s.name for s in local]
            for slot, expr in template.terms:
                for symbol in sorted(expr.free_symbols - local, key=lambda s: s.name):
                    hint = "; use dn.t for the time" if symbol.name == t.name else \
                        _suggest(symbol.name, names)
                    raise ValueError(f"unknown symbol {symbol.name!r} in the term for {slot.name} "
                                     f"of template {number}{hint} (global parameters go in params=, "
                                     "per-cell ones in the template's params=)")
            if template.cells and (template.indices.min() < 0 or template.indices.max() >= self._n):
                e, s = np.argwhere((template.indices < 0) | (template.indices >= self._n))[0]
                raise ValueError(f"template {number} maps slot {template.slots[s].name} of cell {e} "
                                 f"to component {template.indices[e, s]}, outside [0, {self._n})")

    @property
    def N(self):
        return self._n

    @cached_property
    def states(self):
        """State symbols in component order (created on first use: O(N) sympy symbols)."""
        return tuple(sp.Symbol(name) for name in self.names)

    def _is_state(self, symbol):
        # without creating the N state symbols: they are plain Symbols named by ``names``
        return symbol == sp.Symbol(symbol.name) and symbol.name in self.names

    @cached_property
    def _positions(self):
        return {name: i for i, name in enumerate(self.names)}

    def index(self, state):
        """Component index of a state symbol (or of its name)."""
        name = state.name if isinstance(state, sp.Symbol) else state
        try:
            return self._positions[name]
        except (KeyError, TypeError):
            raise ValueError(f"{state!r} is not a state") from None

    @cached_property
    def rhs(self):
        """The right-hand sides as per-component sympy expressions (O(N) symbolic work: for
        checks and small systems; the solver never needs them)."""
        states = self.states
        sums = [[] for _ in range(self.N)]
        for template in self.templates:
            targets = [template.slots.index(slot) for slot, _ in template.terms]
            for e in range(template.cells):
                local = dict(zip(template.slots, (states[i] for i in template.indices[e])))
                local.update(zip(template.params, map(sp.Float, template.values[e])))
                for s, (_, expr) in zip(targets, template.terms):
                    sums[template.indices[e, s]].append(expr.xreplace(local))
        return tuple(sp.Add(*terms) for terms in sums)

    def expand(self):
        """The same system as a per-expression :class:`~dolfinode.ODE` (O(N) symbolic work)."""
        return ODE(dict(zip(self.states, self.rhs)), u0=self.u0, T=self.T, params=self.params,
                   t0=self.t0, nonnegative=self.nonnegative)

    def __getstate__(self):
        # compiled kernels and the O(N) symbol caches are rebuilt where the ODE is unpickled
        state = super().__getstate__()
        for name in ("states", "_positions", "rhs"):
            state.pop(name, None)
        return state

    def __repr__(self):
        return (f"TemplateODE(N={self.N}, templates={len(self.templates)}, t0={self.t0}, "
                f"T={self.T}, params={len(self.params)})")
