"""Lowering of an ODE declaration to compiled kernels.

The passes run in a fixed order:
1. substitute states -> u[i], parameters -> p[j] (so kernels do not depend on names or values);
2. read the dependency graph off each expression's free symbols (no probing);
3. differentiate exactly with sympy, only on the dependency pattern (the sparse Jacobian);
4. generate source with common-subexpression elimination and compile with numba, cached by hash.
"""
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sps
import sympy as sp

from dolfinode.compile.cache import load_module, signature
from dolfinode.compile.codegen import kernel_source
from dolfinode.ode import t as time_symbol


@dataclass(eq=False)
class CompiledODE:
    """Compiled kernels of an ODE and its sparsity.

    Attributes
    ----------
    rhs, rhs_component, jacobian : numba functions (see ``compile.signatures``)
    indptr, indices : int64 CSR pattern of df/du; row i lists the j that f_i depends on
    p : float64 parameter values in the order of ``ode.parameter_symbols``
    compile_time : seconds spent generating and compiling (or loading from cache)
    cached : whether the kernels came from the disk cache
    """

    N: int
    rhs: object
    rhs_component: object
    jacobian: object
    indptr: np.ndarray
    indices: np.ndarray
    p: np.ndarray
    compile_time: float
    cached: bool

    @property
    def nnz(self):
        return len(self.indices)

    def dependencies(self):
        """Dependency graph as a CSR boolean matrix: entry (i, j) if f_i depends on u_j."""
        data = np.ones(self.nnz, dtype=bool)
        return sps.csr_matrix((data, self.indices, self.indptr), shape=(self.N, self.N))

    def f(self, u, t):
        """f(u, t) as a new array (convenience, not for hot loops)."""
        out = np.empty(self.N)
        self.rhs(np.ascontiguousarray(u, dtype=float), float(t), self.p, out)
        return out

    def jacobian_matrix(self, u, t):
        """df/du at (u, t) as a scipy CSR matrix."""
        data = np.empty(self.nnz)
        self.jacobian(np.ascontiguousarray(u, dtype=float), float(t), self.p, data)
        return sps.csr_matrix((data, self.indices.copy(), self.indptr.copy()), shape=(self.N, self.N))


_cache = {}


def lower(ode):
    """Compile ``ode`` to kernels (memoised per declaration and on disk by signature)."""
    start = time.perf_counter()
    u = sp.IndexedBase("u")
    p = sp.IndexedBase("p")
    subs = {s: u[i] for i, s in enumerate(ode.states)}
    subs.update({s: p[j] for j, s in enumerate(ode.parameter_symbols)})
    subs[time_symbol] = sp.Symbol("t")
    rhs = [expr.xreplace(subs) for expr in ode.rhs]
    key = signature(*(sp.srepr(e) for e in rhs))
    if key in _cache:
        kernels, indptr, indices = _cache[key]
        return CompiledODE(ode.N, kernels.rhs, kernels.rhs_component, kernels.jacobian,
                           indptr, indices, ode.parameter_values, 0.0, True)
    index_of = {s: i for i, s in enumerate(ode.states)}
    rows = [sorted(index_of[s] for s in expr.free_symbols if s in index_of) for expr in ode.rhs]
    indptr = np.zeros(ode.N + 1, dtype=np.int64)
    indptr[1:] = np.cumsum([len(r) for r in rows])
    indices = np.array([j for r in rows for j in r], dtype=np.int64)

    def source():
        entries = [sp.diff(rhs[i], u[j]) for i, r in enumerate(rows) for j in r]
        return kernel_source(rhs, entries)

    kernels, cached = load_module(key, source)
    _cache[key] = (kernels, indptr, indices)
    return CompiledODE(ode.N, kernels.rhs, kernels.rhs_component, kernels.jacobian, indptr,
                       indices, ode.parameter_values, time.perf_counter() - start, cached)
