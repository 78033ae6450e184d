"""The ODEs that automatic modeling solves: the full model in a window's local time, and
the reduced model f~ = f + g~ with inactivated components.

Both are built for an :class:`~dolfinode.ODE` of per-component expressions and for a
:class:`~dolfinode.systems.template.TemplateODE` (a lattice of 10^5 masses): for templates the
pieces are templates again, so the generated code does not grow with N and a rebuilt model
(new values of g~ and G) reuses the compiled kernels.
"""
import numpy as np
import sympy as sp

from dolfinode.ensemble import vary
from dolfinode.modeling.manifold import manifold_rates
from dolfinode.ode import ODE, t
from dolfinode.systems.template import Template, TemplateODE


def _fresh(name, taken):
    """A real symbol named ``name`` (underscores appended until it is not in ``taken``)."""
    while name in taken:
        name += "_"
    taken.add(name)
    return sp.Symbol(name, real=True)


def _admissible(ode, u0):
    """u0 with the components declared nonnegative set to max(u0, 0): averages and values
    between nodes may dip below zero by the tolerance."""
    return np.where(ode.nonnegative, np.maximum(u0, 0.0), u0)


def _taken(ode):
    names = {s.name for s in ode.params} | {t.name}
    if isinstance(ode, TemplateODE):
        for template in ode.templates:
            names |= {s.name for s in (*template.slots, *template.params)}
    else:
        names |= {s.name for s in ode.states}
    return names


class WindowModel:
    """The full model ``ode`` in the local time s = t - shift of a resolved window.

    In absolute time, steps of the fast scale lose their last digits to the rounding of
    t + k (at t = 90, steps of 3e-11 are represented to 5e-4 only), so a window is solved
    on [0, 2 tau] with t replaced by s + shift, the shift being a parameter.
    """

    def __init__(self, ode):
        self.ode = ode
        self.shift = _fresh("t_window", _taken(ode))
        self._last = None  # the last declaration
        moved = {t: t + self.shift}
        if isinstance(ode, TemplateODE):
            self._templates = tuple(
                Template(tp.slots, {s: e.xreplace(moved) for s, e in tp.terms}, tp.indices,
                         tp.params, tp.values) for tp in ode.templates)
        else:
            self._rhs = {s: e.xreplace(moved) for s, e in zip(ode.states, ode.rhs)}

    def declaration(self, u0, t0, T, shift):
        """The window's ODE on [t0, T] (local time) from u0, for the window starting at
        absolute time ``shift``.

        The expressions are declared (and checked by sympy) once, later declarations vary
        the first (:func:`~dolfinode.vary`: re-declaring is a sizeable part of a small
        modeling solve). Declarations of one window (the same shift) share their lowering,
        kernels and band ordering, which are costly to redo for each piece on large systems."""
        u0 = _admissible(self.ode, u0)
        if self._last is not None:
            ode = vary(self._last, {self.shift: float(shift), "u0": u0, "t0": t0, "T": T})
            if self._last.params == ode.params:
                ode._compiled = getattr(self._last, "_compiled", None)
        elif isinstance(self.ode, TemplateODE):
            ode = TemplateODE(self._templates, u0=u0, T=T, params=self._params(shift), t0=t0,
                              names=self.ode.names, nonnegative=self.ode.nonnegative)
        else:
            ode = ODE(self._rhs, u0=u0, T=T, t0=t0, params=self._params(shift),
                      nonnegative=self.ode.nonnegative)
        self._last = ode
        return ode

    def _params(self, shift):
        return {**self.ode.params, self.shift: float(shift)}


class ReducedDeclaration:
    """The reduced ODE  u~_i' = f_i(u~) + c_i + sum_j G_ij u~_j  (active i),  u~_i' = 0
    (frozen i), the rates of the slow manifold f_S = 0 (slaved i, see
    :mod:`dolfinode.modeling.manifold`), with c and the entries of G on a fixed pattern as
    parameters.

    Parameters
    ----------
    ode : ODE or TemplateODE, the full model
    active : bool array (N,)
    pattern : (rows, cols) int arrays of the entries of G, or None for a constant g~
    slaved : bool array (N,) of inactive components on their manifold (none for a
        TemplateODE), or None
    """

    def __init__(self, ode, active, pattern=None, slaved=None):
        self.ode, self.active = ode, np.asarray(active, dtype=bool)
        self.pattern = pattern
        taken = _taken(ode)
        rows = np.flatnonzero(self.active)
        if isinstance(ode, TemplateODE):
            self._templates = self._masked_templates(taken)
            w, z = _fresh("w", taken), _fresh("z", taken)
            self._c = _fresh("g", taken)
            self._templates.append(Template((w,), {w: self._c}, rows[:, None], (self._c,),
                                            np.zeros((rows.size, 1))))
            if pattern is not None and len(pattern[0]):
                self._G = _fresh("G", taken)
                self._affine = Template((w, z), {w: self._G * z},
                                        np.column_stack(pattern), (self._G,),
                                        np.zeros((len(pattern[0]), 1)))
            else:
                self._affine = None
        else:
            self._c = [_fresh(f"g_{s.name}", taken) for s in ode.states]
            rhs = [e + c if a else sp.S.Zero
                   for e, c, a in zip(ode.rhs, self._c, self.active)]
            self._G = []
            if pattern is not None:
                for i, j in zip(*pattern):
                    G = _fresh(f"G_{i}_{j}", taken)
                    self._G.append(G)
                    rhs[i] = rhs[i] + G * ode.states[j]
            if slaved is not None and np.any(slaved):
                rates = iter(manifold_rates(ode.states, [e for e, s in zip(ode.rhs, slaved) if s],
                                            rhs, slaved))
                rhs = [next(rates) if s else e for e, s in zip(rhs, slaved)]
            self._rhs = dict(zip(ode.states, rhs))
            self._declared = None

    def _masked_templates(self, taken):
        """The full model's templates with every term multiplied by a per-cell 0/1 factor:
        contributions to inactive components vanish."""
        masked = []
        for tp in self.ode.templates:
            factors, terms, values = [], {}, [tp.values]
            for slot, expr in tp.terms:
                a = _fresh(f"active_{slot.name}", taken)
                factors.append(a)
                terms[slot] = a * expr
                values.append(self.active[tp.indices[:, tp.slots.index(slot)]][:, None])
            masked.append(Template(tp.slots, terms, tp.indices, (*tp.params, *factors),
                                   np.hstack(values).astype(float)))
        return masked

    def declaration(self, u0, t0, T, c, G=None):
        """The reduced ODE on [t0, T] from u0, with constant part c (N,) and G's entries
        on the pattern (or None)."""
        c = np.where(self.active, c, 0.0)
        u0 = _admissible(self.ode, u0)
        if isinstance(self.ode, TemplateODE):
            templates = list(self._templates)
            rows = np.flatnonzero(self.active)
            constant = templates[-1]
            templates[-1] = Template(constant.slots, dict(constant.terms), constant.indices,
                                     constant.params, c[rows][:, None])
            if self._affine is not None:
                a = self._affine
                templates.append(Template(a.slots, dict(a.terms), a.indices, a.params,
                                          np.asarray(G, dtype=float)[:, None]))
            return TemplateODE(templates, u0=u0, T=T, params=self.ode.params, t0=t0,
                               names=self.ode.names, nonnegative=self.ode.nonnegative)
        values = dict(zip(self._c, c))
        if self._G:
            values.update(zip(self._G, G))
        if self._declared is None:  # declared (and checked by sympy) once, then varied
            self._declared = ODE(self._rhs, u0=u0, T=T, t0=t0,
                                 params={**self.ode.params, **values},
                                 nonnegative=self.ode.nonnegative)
            return self._declared
        return vary(self._declared, {**values, "u0": u0, "t0": t0, "T": T})
