"""Lowering of an ODE declaration to compiled kernels.

The passes run in a fixed order:
1. substitute states -> u[i], parameters -> p[j] (so kernels do not depend on names or values);
2. read the dependency graph off each expression's free symbols (no probing);
3. differentiate exactly with sympy, only on the dependency pattern (the sparse Jacobian);
4. generate C with common-subexpression elimination and compile it, cached by hash.

A large system whose right-hand sides take few shapes (a stencil, a lattice declared one
expression per component) is lowered instead as templates, one per shape (``_shapes``):
differentiated and printed once per shape, with code that does not grow with N.
"""
import hashlib
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sps
import sympy as sp

from dolfinode.compile.cache import load_library, signature
from dolfinode.compile.codegen import kernel_source
from dolfinode.compile.signatures import KERNELS, Kernel, call_rhs
from dolfinode.linalg import bandwidth_ordering
from dolfinode.linalg.newton_matrix import band_structure, sparse_structure
from dolfinode.ode import t as time_symbol


@dataclass(eq=False)
class CompiledODE:
    """Compiled kernels of an ODE and its sparsity.

    Attributes
    ----------
    rhs, rhs_component, jacobian, jacobian_row : :class:`~dolfinode.compile.signatures.Kernel`
    indptr, indices : int64 CSR pattern of df/du; row i lists the j that f_i depends on
    p : float64 parameter values in the order of ``ode.parameter_symbols`` (for a
        TemplateODE followed by the header that locates its arrays, see
        :mod:`dolfinode.compile.template`)
    compile_time : seconds spent generating and compiling (or loading from cache)
    cached : whether the kernels came from the disk cache
    data : arrays the kernels read through ``p`` (kept alive with the kernels)
    templates : how many templates the kernels loop over (a TemplateODE's, or the shapes of
        an expression system lowered by shape); 0 for code per expression
    newton_plans : the Newton matrices' storage and cost estimates per method, made by the
        first solve that asks (:func:`dolfinode.solve._newton_plan`)
    header : the template header that follows the parameter values in ``p`` (None: ``p``
        is the parameter values)
    derived : the orderings and structures derived from the pattern (see ``_derived``)
    workspaces : loop workspaces a finished solve left for the next one, by method (see
        :func:`dolfinode.solve._carried`); shared, as ``derived``, by every :meth:`again` copy
    growth_basis : [the eigenbasis of the step the growth check decomposed last, or None]
        (:func:`dolfinode.growth.spanned_growth`: a later check starts from it); shared, as
        ``derived``
    """

    N: int
    rhs: Kernel
    rhs_component: Kernel
    jacobian: Kernel
    jacobian_row: Kernel
    indptr: np.ndarray
    indices: np.ndarray
    p: np.ndarray
    compile_time: float
    cached: bool
    data: tuple = ()
    templates: int = 0
    newton_plans: dict = field(default_factory=dict)
    header: np.ndarray = None
    derived: dict = field(default_factory=dict)
    workspaces: dict = field(default_factory=dict)
    growth_basis: list = field(default_factory=lambda: [None])

    def again(self, values):
        """This lowering as a later ``lower`` of the same ODE returns it: loaded, no compile
        time, with ``p`` made from the parameter values as they are now (they may have been
        set since); the band ordering, once computed, is kept (a shallow copy without copy.copy's
        protocol, which a small solve notices)."""
        again = object.__new__(CompiledODE)
        again.__dict__.update(self.__dict__)
        again.compile_time, again.cached = 0.0, True
        again.p = _parameter_vector(values, self.header)
        return again

    @property
    def nnz(self):
        return len(self.indices)

    def _derived(self, name, make):
        """A value derived from the pattern, made once and shared with every :meth:`again`
        copy (a cached_property of a copy was lost with it: each small solve made its band
        structure afresh)."""
        if name not in self.derived:
            self.derived[name] = make()
        return self.derived[name]

    @property
    def _pattern_key(self):
        return self._derived("pattern key", lambda: hashlib.blake2b(
            self.indptr.tobytes() + self.indices.tobytes(), digest_size=16).digest())

    @property
    def ordering(self):
        """(order, position, kl, ku): the component ordering that narrows the Jacobian's band
        (remembered by sparsity pattern: automatic modeling solves one pattern dozens of
        times, with new parameter values)."""
        return self._derived("ordering", lambda: _remembered(
            _orderings, self._pattern_key,
            lambda: bandwidth_ordering(self.indptr, self.indices, self.N)))

    @property
    def band_structure(self):
        """The banded storage of the Newton matrices I - c J in the band ordering."""
        _, position, kl, ku = self.ordering
        return self._derived("band structure", lambda: band_structure(position, kl, ku))

    @property
    def sparse_structure(self):
        """The sparse storage of the Newton matrices I - c J
        (:func:`dolfinode.linalg.newton_matrix.sparse_structure`; remembered by sparsity
        pattern)."""
        return self._derived("sparse structure", lambda: _remembered(
            _structures, self._pattern_key,
            lambda: sparse_structure(self.indptr, self.indices, self.N)))

    def dependencies(self):
        """Dependency graph as a CSR boolean matrix: entry (i, j) if f_i depends on u_j."""
        data = np.ones(self.nnz, dtype=bool)
        return sps.csr_matrix((data, self.indices, self.indptr), shape=(self.N, self.N))

    def _vector(self, u):
        u = np.ascontiguousarray(u, dtype=float)
        if u.shape != (self.N,):
            raise ValueError(f"u must have shape ({self.N},), got {u.shape}")
        return u

    def f(self, u, t):
        """f(u, t) as a new array (convenience, not for hot loops)."""
        out = np.empty(self.N)
        call_rhs(self.rhs.address, self._vector(u), float(t), self.p, out)
        return out

    def f_component(self, i, u, t):
        """f_i(u, t), at a cost proportional to the number of states f_i depends on."""
        if not 0 <= i < self.N:
            raise IndexError(f"component {i} out of range for N = {self.N}")
        out = np.empty(1)
        self.rhs_component(int(i), self._vector(u).ctypes.data, float(t), self.p.ctypes.data,
                           out.ctypes.data)
        return out[0]

    def jacobian_row_values(self, i, u, t):
        """Row i of df/du at (u, t): values at columns indices[indptr[i]:indptr[i + 1]]."""
        if not 0 <= i < self.N:
            raise IndexError(f"component {i} out of range for N = {self.N}")
        out = np.empty(max(self.indptr[i + 1] - self.indptr[i], 1))
        self.jacobian_row(int(i), self._vector(u).ctypes.data, float(t), self.p.ctypes.data,
                          out.ctypes.data)
        return out[:self.indptr[i + 1] - self.indptr[i]]

    def jacobian_matrix(self, u, t):
        """df/du at (u, t) as a scipy CSR matrix."""
        data = np.empty(self.nnz)
        call_rhs(self.jacobian.address, self._vector(u), float(t), self.p, data)
        return sps.csr_matrix((data, self.indices.copy(), self.indptr.copy()), shape=(self.N, self.N))


#: How many lowerings of expression ODEs, band orderings and sparse Newton structures are
#: remembered (oldest dropped).
REMEMBERED = 16
_loaded = {}
_orderings = {}
_structures = {}
_lowerings = {}


def _remembered(store, key, make):
    """store[key], made by ``make()`` when missing; the oldest entry is dropped to keep
    REMEMBERED."""
    if key not in store:
        if len(store) >= REMEMBERED:
            del store[next(iter(store))]
        store[key] = make()
    return store[key]


#: An expression ODE of at least STRUCTURED_MIN components whose right-hand sides take at
#: most one shape per STRUCTURED_RATIO components is lowered as templates (``_shapes``);
#: its slots are named dn_slot_0, dn_slot_1, ... (a system with a parameter so named is not).
STRUCTURED_MIN = 256
STRUCTURED_RATIO = 8
_SLOT = "dn_slot_"


def _clamp_powers(expr, clamp):
    """``expr`` with u_i**a (a not an integer: sqrt(u_i), u_i**0.5, ...) read as
    max(u_i, 0)**a for the components in ``clamp`` (declared nonnegative): defined on iterates
    that dip below 0, where the power is nan; a step that leaves [-atol, inf) is still cut.
    Elsewhere u_i is read as it is: for polynomial kinetics f's own continuation below 0
    pushes back (ROBER's y2' = ... - 1e4 y2 y3), which a constant one would not."""
    if not clamp:
        return expr
    return expr.replace(lambda e: e.is_Pow and e.base in clamp and not e.exp.is_integer,
                        lambda e: sp.Pow(clamp[e.base], e.exp, evaluate=False))


def _derivative(expr, x):
    """d expr / dx, with the derivatives of piecewise-constant functions (sign, Heaviside,
    floor, ceiling) set to their value zero almost everywhere."""
    d = sp.diff(expr, x)
    if d.has(sp.DiracDelta, sp.Derivative):
        d = d.replace(lambda e: isinstance(e, (sp.DiracDelta, sp.Derivative)), lambda e: sp.S.Zero)
        # the chain rule through such a function of an expression, floor(3 x), leaves
        # Subs(0, xi, 3 x): evaluated to 0 (printed, it was not C)
        d = d.replace(lambda e: isinstance(e, sp.Subs), lambda e: e.doit())
    return d


def lower(ode):
    """Compile ``ode`` to kernels (memoised on the declaration, and on disk by signature)."""
    if getattr(ode, "_compiled", None) is not None:
        return ode._compiled.again(ode.parameter_values)
    start = time.perf_counter()
    from dolfinode.compile.template import lower_templates, templates_in  # it imports this module

    if hasattr(ode, "templates"):
        lowered = lower_templates(ode.N, ode.templates, ode.parameter_symbols)
    else:
        declared = (tuple(ode.states), tuple(ode.rhs), tuple(ode.parameter_symbols),
                    tuple(np.flatnonzero(ode.nonnegative)))
        lowered = _remembered(_lowerings, declared, lambda: _lower_expressions(ode))
    key, source, indptr, indices, header, data = lowered
    p = _parameter_vector(ode.parameter_values, header)
    templates = 0 if header is None else templates_in(header)
    cached = key in _loaded
    if not cached:
        library, cached = load_library(key, source)
        _loaded[key] = tuple(Kernel(library, name) for name in KERNELS)
    kernels = _loaded[key]
    ode._compiled = CompiledODE(ode.N, *kernels, indptr, indices, p,
                                time.perf_counter() - start, cached, data, templates,
                                header=header)
    return ode._compiled


def _parameter_vector(values, header):
    """``p`` of the kernels: the parameter values, followed by the template header if any."""
    if header is None:
        return values
    from dolfinode.compile.template import kernel_parameters  # it imports this module

    return kernel_parameters(values, header)


def _shapes(ode, rows):
    """The right-hand sides as templates, one per shape, with the slots each clamps (see
    :func:`_clamp_powers`); None when they take more than one shape per STRUCTURED_RATIO
    components, or the system is small.

    The shape of f_i is f_i with the states of its cell, the components it depends on and i
    itself in increasing order, renamed to slots s_0, s_1, ... (and which of them are
    declared nonnegative): the interior points of a stencil share one
    (u_(i-1) - 2 u_i + u_(i+1) -> s_0 - 2 s_1 + s_2 on s_1). Lowered as templates, each shape
    is differentiated and printed once and the kernels loop over its cells, so neither the
    symbolic work nor the code grows with N.
    """
    n = ode.N
    if n < STRUCTURED_MIN or any(s.name.startswith(_SLOT) for s in ode.parameter_symbols):
        return None
    from dolfinode.systems.template import Template

    slots = sp.symbols(f"{_SLOT}0:{max(len(r) for r in rows) + 1}", real=True)
    nonnegative = ode.nonnegative
    shapes = {}
    for i, (expr, row) in enumerate(zip(ode.rhs, rows)):
        cell = row if i in row else sorted([*row, i])
        canonical = expr.xreplace({ode.states[j]: slots[m] for m, j in enumerate(cell)})
        clamped = tuple(m for m, j in enumerate(cell) if nonnegative[j])
        cells = shapes.setdefault((canonical, cell.index(i), len(cell), clamped), [])
        if len(shapes) * STRUCTURED_RATIO > n:
            return None
        cells.append(cell)
    templates = [Template(slots[:size], {slots[target]: canonical}, indices=cells)
                 for (canonical, target, size, _), cells in shapes.items()]
    return templates, [clamped for *_, clamped in shapes]


def _lower_expressions(ode):
    """Signature, source maker, CSR pattern, kernel header and kept arrays of an ODE of
    per-component expressions (as :func:`dolfinode.compile.template.lower_templates`; header
    None: ``p`` is the parameter values)."""
    index_of = {s: i for i, s in enumerate(ode.states)}
    rows = [sorted(index_of[s] for s in expr.free_symbols if s in index_of) for expr in ode.rhs]
    shapes = _shapes(ode, rows)
    if shapes is not None:
        from dolfinode.compile.template import lower_templates

        templates, clamped = shapes
        return lower_templates(ode.N, templates, ode.parameter_symbols, exclusive=True,
                               clamped=clamped)
    # Real symbols named as the C array accesses they print as: real, so that sympy
    # differentiates |u|, sign(u), ... as functions of a real variable.
    u = [sp.Symbol(f"u[{i}]", real=True) for i in range(ode.N)]
    subs = dict(zip(ode.states, u))
    subs.update({s: sp.Symbol(f"p[{j}]", real=True) for j, s in enumerate(ode.parameter_symbols)})
    subs[time_symbol] = sp.Symbol("t", real=True)
    rhs = [expr.xreplace(subs) for expr in ode.rhs]
    nonnegative = [int(i) for i in np.flatnonzero(ode.nonnegative)]
    key = signature(*(sp.srepr(e) for e in rhs),
                    *(f"nonnegative {i} in non-integer powers" for i in nonnegative))
    indptr = np.zeros(ode.N + 1, dtype=np.int64)
    indptr[1:] = np.cumsum([len(r) for r in rows])
    indices = np.array([j for r in rows for j in r], dtype=np.int64)

    def source():
        jacobian_rows = [[_derivative(rhs[i], u[j]) for j in r] for i, r in enumerate(rows)]
        clamp = {u[i]: sp.Symbol(f"fmax(u[{i}], 0.0)", real=True) for i in nonnegative}
        return kernel_source([_clamp_powers(e, clamp) for e in rhs],
                             [[_clamp_powers(e, clamp) for e in row] for row in jacobian_rows])

    return key, source, indptr, indices, None, ()
