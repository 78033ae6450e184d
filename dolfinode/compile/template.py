"""Lowering of a :class:`~dolfinode.systems.template.TemplateODE` (and of a structured ODE of
expressions, one template per shape, see ``lowering._shapes``) to the standard kernels.

The kernels have the signatures of :mod:`dolfinode.compile.signatures`, so every solver
loop uses them unchanged. The passes, in order:

1. substitute slots -> U[k], per-cell parameters -> P[k], global parameters -> p[j];
2. differentiate each term exactly with sympy on its own slots (the local Jacobians);
3. generate C once per set of template expressions: loops over cells that gather U from
   u, evaluate the terms (with common subexpressions shared inside a cell) and scatter-add
   into f or into the Jacobian's CSR values; compiled and cached by a signature that does
   not involve N or the arrays;
4. in numpy, from the index arrays: the global CSR pattern of df/du, the CSR position of
   every local Jacobian entry, and the incidence component -> (cell, term) used by f_i and
   row i of the Jacobian, which therefore touch only the cells of component i.

The arrays reach the kernels through ``p``: after the global parameter values p[0..G)
comes a header of int64 words (N, nnz, the address of indptr, then per template: cells
and the addresses of its index, value, incidence and position arrays), read in C as a
struct. The :class:`~dolfinode.compile.lowering.CompiledODE` keeps the arrays alive.
Contributions to one component are summed in the same order (template, cell, term) by the
full and the single-component kernels, so f_i equals f[i] bit for bit.
"""
import re

import numpy as np
import sympy as sp

from dolfinode.compile.cache import signature
from dolfinode.compile.codegen import _PROLOGUE, _statements
from dolfinode.compile.lowering import _clamp_powers, _derivative
from dolfinode.compile.pattern import assemble_pattern
from dolfinode.ode import t as time_symbol

_SLOT_READ = re.compile(r"\bU\[(\d+)\]")
_STRUCTS = """\
#include <stdint.h>
typedef struct {
    int64_t cells;
    const int64_t *index;     /* cells x slots: the global component of each slot */
    const double *values;     /* cells x parameters */
    const int64_t *first;     /* N + 1: incidence of component i in first[i]..first[i+1] */
    const int64_t *incidence; /* cell * terms + term, sorted by the term's component */
    const int64_t *position;  /* cells x entries: CSR position of each local Jacobian entry */
} dn_cells;
typedef struct {
    int64_t n, nnz;
    const int64_t *indptr;
    dn_cells cells[%d];
} dn_system;
#define SYSTEM ((const dn_system *)(p + %d))
"""


class _LocalTemplate:
    """One template with C-named symbols: terms on target slots and their local Jacobian;
    the slots in ``clamped`` (of components declared nonnegative) are read as max(U_k, 0)
    inside non-integer powers, as :func:`dolfinode.compile.lowering._clamp_powers`."""

    def __init__(self, template, global_subs, clamped=()):
        subs = dict(global_subs)
        subs.update({s: sp.Symbol(f"U[{k}]", real=True) for k, s in enumerate(template.slots)})
        subs.update({s: sp.Symbol(f"P[{k}]", real=True) for k, s in enumerate(template.params)})
        self.slots, self.params = len(template.slots), len(template.params)
        self.targets = [template.slots.index(s) for s, _ in template.terms]
        self.exprs = [expr.xreplace(subs) for _, expr in template.terms]
        local = [subs[s] for s in template.slots]
        # deps[m]: the slots term m depends on; derivative entries are numbered term by term
        self.deps = [sorted(k for k, s in enumerate(local) if s in expr.free_symbols)
                     for expr in self.exprs]
        self.offsets = np.concatenate([[0], np.cumsum([len(d) for d in self.deps])]).astype(int)
        self._local = local
        self.clamped = tuple(clamped)
        self._clamp = {local[k]: sp.Symbol(f"fmax(U[{k}], 0.0)", real=True) for k in clamped}
        self.kernel_exprs = [_clamp_powers(e, self._clamp) for e in self.exprs]

    @property
    def entries(self):
        return int(self.offsets[-1])

    def key(self):
        return "|".join([str(self.slots), str(self.params), str(self.targets)]
                        + [sp.srepr(e) for e in self.exprs]
                        + ([f"clamped {self.clamped}"] if self.clamped else []))

    def derivatives(self, m):
        return [_clamp_powers(_derivative(self.exprs[m], self._local[r]), self._clamp)
                for r in self.deps[m]]

    def entry_slots(self):
        """(rows, columns): the slots of every local Jacobian entry, in entry order."""
        rows = np.repeat(self.targets, [len(d) for d in self.deps]).astype(np.int64)
        columns = np.array([r for d in self.deps for r in d], dtype=np.int64)
        return rows, columns


def _gather(slots_used):
    return [f"        U[{k}] = u[I[{k}]];" for k in sorted(slots_used)]


def _used_slots(exprs):
    """The slots read by ``exprs`` (as U[k], or clamped as fmax(U[k], 0.0))."""
    return {int(k) for e in exprs for s in e.free_symbols for k in _SLOT_READ.findall(s.name)}


def _cell_loop(number, local, body, used):
    """A loop over the cells of template ``number`` running ``body`` (C lines) per cell."""
    return [f"    {{ const dn_cells *c = &SYSTEM->cells[{number}];",
            "      for (int64_t e = 0; e < c->cells; ++e) {",
            f"        const int64_t *I = c->index + e * {local.slots};",
            f"        const double *P = c->values + e * {local.params}; (void)P;",
            f"        const int64_t *J = c->position + e * {local.entries}; (void)J;",
            f"        double U[{local.slots}];"] + _gather(used) + \
        ["    " + line for line in body] + ["      }", "    }"]


def _incidence_loop(number, local, cases):
    """A loop over the (cell, term) pairs of component i in template ``number``; ``cases[m]``
    are the C lines for term m."""
    lines = [f"    {{ const dn_cells *c = &SYSTEM->cells[{number}];",
             "      for (int64_t k = c->first[i]; k < c->first[i + 1]; ++k) {",
             f"        const int64_t e = c->incidence[k] / {len(local.exprs)};",
             f"        const int64_t *I = c->index + e * {local.slots};",
             f"        const double *P = c->values + e * {local.params}; (void)P;",
             f"        const int64_t *J = c->position + e * {local.entries}; (void)J;",
             f"        double U[{local.slots}];",
             f"        switch (c->incidence[k] % {len(local.exprs)}) {{"]
    for m, (used, body) in enumerate(cases):
        lines += [f"        case {m}: {{"] + _gather(used) + ["    " + line for line in body]
        lines += ["            break;", "        }"]
    return lines + ["        }", "      }", "    }"]


def template_source(locals_, parameters, exclusive=False):
    """C source of the four kernels of :mod:`dolfinode.compile.signatures` for templates;
    ``exclusive``: every component is the target of one term of one cell (so f and df/du are
    assigned, not zeroed and summed)."""
    lines = [_PROLOGUE, _STRUCTS % (len(locals_), parameters)]
    add = "=" if exclusive else "+="
    # f: zero, then every template scatters its terms
    lines += ["void dn_rhs(ARGS, double *restrict out) {"]
    if not exclusive:
        lines += ["    for (int64_t i = 0; i < SYSTEM->n; ++i) out[i] = 0.0;"]
    for n, local in enumerate(locals_):
        body = _statements(local.kernel_exprs, [f"out[I[{s}]]" for s in local.targets], add)
        lines += _cell_loop(n, local, body, _used_slots(local.kernel_exprs))
    lines += ["}", ""]
    # f_i: the terms of the cells incident to i
    lines += ["void dn_rhs_component(long i, ARGS, double *restrict out) {", "    double f = 0.0;"]
    for n, local in enumerate(locals_):
        cases = [(_used_slots([e]), _statements([e], ["f"], "+=")) for e in local.kernel_exprs]
        lines += _incidence_loop(n, local, cases)
    lines += ["    out[0] = f;", "}", ""]
    # df/du: zero, then every local Jacobian entry added at its CSR position
    derivatives = [[local.derivatives(m) for m in range(len(local.exprs))] for local in locals_]
    lines += ["void dn_jacobian(ARGS, double *restrict data) {"]
    if not exclusive:
        lines += ["    for (int64_t k = 0; k < SYSTEM->nnz; ++k) data[k] = 0.0;"]
    for n, local in enumerate(locals_):
        flat = [d for term in derivatives[n] for d in term]
        body = _statements(flat, [f"data[J[{k}]]" for k in range(len(flat))], add) if flat else []
        lines += _cell_loop(n, local, body, _used_slots(flat))
    lines += ["}", ""]
    # row i of df/du: the local Jacobian rows of the terms incident to i
    lines += ["void dn_jacobian_row(long i, ARGS, double *restrict out) {",
              "    const int64_t start = SYSTEM->indptr[i];",
              "    for (int64_t k = start; k < SYSTEM->indptr[i + 1]; ++k) out[k - start] = 0.0;"]
    for n, local in enumerate(locals_):
        cases = []
        for m, ds in enumerate(derivatives[n]):
            targets = [f"out[J[{local.offsets[m] + r}] - start]" for r in range(len(ds))]
            cases.append((_used_slots(ds), _statements(ds, targets, "+=") if ds else []))
        lines += _incidence_loop(n, local, cases)
    lines += ["}", ""]
    return "\n".join(lines)


def _pattern(n, templates, locals_):
    """CSR pattern (indptr, indices) of df/du and the CSR position of every local entry."""
    return assemble_pattern(n, [(template.indices, *local.entry_slots())
                                for local, template in zip(locals_, templates)])


def _incidence(template, local, n):
    """first (N + 1) and incidence: the (cell * terms + term) codes grouped by component."""
    components = template.indices[:, local.targets].ravel()  # code = flat position
    incidence = np.argsort(components, kind="stable").astype(np.int64)
    first = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(components, minlength=n), out=first[1:])
    return first, incidence


def lower_templates(n, templates, parameter_symbols, exclusive=False, clamped=None):
    """Signature, source maker, CSR pattern and kernel header of templates over n components
    with the global parameters ``parameter_symbols``; ``clamped``: per template, the slots
    read as max(U_k, 0) in non-integer powers (see :class:`_LocalTemplate`).

    Returns (key, source, indptr, indices, header, keep): ``source()`` generates the C code,
    ``header`` holds the int64 words that follow the parameter values in ``p`` (see
    :func:`kernel_parameters`), ``keep`` the arrays they point to.
    """
    global_subs = {s: sp.Symbol(f"p[{j}]", real=True) for j, s in enumerate(parameter_symbols)}
    global_subs[time_symbol] = sp.Symbol("t", real=True)
    locals_ = [_LocalTemplate(template, global_subs, slots)
               for template, slots in zip(templates, clamped or [()] * len(templates))]
    count = len(parameter_symbols)
    key = signature("template", str(count), *(local.key() for local in locals_),
                    *(["exclusive"] if exclusive else []))
    indptr, indices, positions = _pattern(n, templates, locals_)
    header = [n, len(indices), indptr.ctypes.data]
    keep = [indptr, indices]
    for template, local, position in zip(templates, locals_, positions):
        first, incidence = _incidence(template, local, n)
        arrays = [template.indices, template.values, first, incidence, position]
        keep += arrays
        header += [template.cells] + [a.ctypes.data for a in arrays]
    return (key, lambda: template_source(locals_, count, exclusive), indptr, indices,
            np.array(header, dtype=np.int64), tuple(keep))


def templates_in(header):
    """How many templates a header of :func:`lower_templates` describes: three words, then
    six per template."""
    return (len(header) - 3) // 6


def kernel_parameters(values, header):
    """``p`` of template kernels: the global parameter values, then the header's words."""
    p = np.zeros(len(values) + len(header))
    p[:len(values)] = values
    p[len(values):].view(np.int64)[:] = header
    return p
