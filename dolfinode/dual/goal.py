"""Goals: the output quantity whose error the dual problem measures.

A goal is the functional

    M(u) = G(u(T)) + int_{t0}^{T} g(u(t), t) dt,

linear (G(u) = (psi_T, u), g(u, t) = (psi_I, u)) or a sympy expression of the states, which the
dual problem linearises at the computed solution U: its data are the gradients
psi = grad G(U(T)) (final value of the dual) and grad g(U(t), t) (source of the dual).
"""
from collections.abc import Mapping, Sequence

import numpy as np
import sympy as sp
from sympy.core.function import AppliedUndef

from dolfinode.compile.lowering import _derivative
from dolfinode.features import NONE, narrow_features
from dolfinode.ode import t as time_symbol


class Goal:
    """The output M(u) = G(u(T)) + int_{t0}^{T} g(u(t), t) dt whose error is estimated.

    Parameters
    ----------
    final : dict, sequence, sympy expression or None
        G: a dict by state symbol or name (missing states weigh 0) or a sequence of N weights
        for the linear output (psi_T, u(T)); or a sympy expression of the states (and the ODE's
        parameters) such as a distance between two masses.
    integral : same forms, or None
        g: the integrand of the time-integrated output; an expression may also contain ``dn.t``.

    Notes
    -----
    ``dn.estimate_error`` and ``dn.solve(..., goal=...)`` also accept the short forms: a dict,
    sequence or expression alone (a final-time goal) and the pair ``("integral", psi)``.
    """

    def __init__(self, final=None, integral=None):
        if final is None and integral is None:
            raise ValueError("a Goal needs final=..., integral=..., or both")
        self.final = final
        self.integral = integral

    @classmethod
    def parse(cls, goal):
        """Turn any accepted goal form into a :class:`Goal`."""
        if isinstance(goal, Goal):
            return goal
        if isinstance(goal, tuple) and len(goal) == 2 and isinstance(goal[0], str):
            kind, psi = goal
            if kind.lower() == "integral":
                return cls(integral=psi)
            if kind.lower() == "final":
                return cls(final=psi)
            raise ValueError(f"unknown goal kind {kind!r}: use ('final', psi) or "
                             "('integral', psi)")
        if goal is None:
            raise TypeError("goal is None: give a dict by state, a vector, a sympy expression "
                            "of the states, ('integral', psi) or a dn.Goal")
        return cls(final=goal)

    def __repr__(self):
        return f"Goal(final={self.final!r}, integral={self.integral!r})"


class _Functional:
    """One part (G or g) of a goal, resolved for an ODE: a constant weight vector or the
    gradient of an expression, evaluated on arrays of states.

    Attributes
    ----------
    breakpoints : ndarray
        The times in (t0, T) where an integrand g(u, t) jumps in t (a window of t).
    features : Features
        Its narrow features in t (a pulse as a kernel for an interior time), as
        :func:`dolfinode.features.narrow_features` finds them in f.
    """

    def __init__(self, spec, ode, what, allow_time):
        self.N = ode.N
        self.weights = None
        self.gradient = None
        self.expression = None  # G (or g) itself, for an expression
        self.breakpoints = np.empty(0)
        self.features = NONE
        if isinstance(spec, sp.Basic):
            self._expression(spec, ode, what, allow_time)
        else:
            self.weights = _weights(spec, ode, what)

    def _expression(self, expr, ode, what, allow_time):
        if not isinstance(expr, sp.Expr):
            raise TypeError(f"the {what} goal must be a scalar sympy expression, got {expr!r}")
        expr = expr.subs(dict(zip(ode.parameter_symbols, ode.parameter_values)))
        allowed = set(ode.states) | ({time_symbol} if allow_time else set())
        stray = sorted(str(s) for s in expr.free_symbols - allowed)
        if stray:
            extra = " and dn.t" if allow_time else ""
            raise ValueError(f"the {what} goal uses {', '.join(stray)}, which are not states of "
                             f"the ODE; use the states {', '.join(map(str, ode.states))}{extra}")
        if expr.has(sp.DiracDelta):
            # lambdify has no DiracDelta: the dual's source would be zero, the estimate too
            raise ValueError(f"the {what} goal {expr} holds a DiracDelta, which the integral "
                             "goal cannot take; for the output u(t1) at a time t1 inside "
                             "[t0, T], estimate the error of a solve with T = t1 (the steps "
                             "after t1 do not change it)")
        undefined = sorted(str(f.func) for f in expr.atoms(AppliedUndef))
        if undefined:
            raise ValueError(f"the {what} goal {expr} uses the undefined function "
                             f"{', '.join(undefined)}; write the goal with sympy's functions")
        # real states, as the kernels' Jacobian takes them: |u|' is then sign(u), not a
        # Derivative(re(u), u) that NumPy cannot print
        real = [sp.Dummy(s.name, real=True) for s in ode.states]
        expr_real = expr.xreplace(dict(zip(ode.states, real)))
        grad = [_derivative(expr_real, s) for s in real]
        if all(g == 0 for g in grad):
            raise ValueError(f"the {what} goal {expr} does not depend on the states")
        function = sp.lambdify((real, time_symbol), grad, modules="numpy")
        self.expression = sp.lambdify((real, time_symbol), expr_real, modules="numpy")
        try:
            function(list(ode.u0), ode.t0)
        except NameError as error:
            raise ValueError(f"the {what} goal {expr} uses a function NumPy cannot evaluate "
                             f"({error}); write it with elementary functions") from None

        def gradient(U, times):
            columns = function(list(U), times)
            return np.array([np.broadcast_to(np.asarray(c, dtype=float), times.shape)
                             for c in columns])

        self.gradient = gradient
        if allow_time and expr.has(time_symbol):
            self.breakpoints, self.features = _time_structure(expr, ode)

    def at(self, U, times):
        """Weights (N, M) at the states U (N, M) and times (M,)."""
        if self.weights is not None:
            return np.repeat(self.weights[:, None], len(times), axis=1)
        values = self.gradient(U, times)
        if not np.all(np.isfinite(values)):
            raise ValueError("the goal's gradient is not finite at the computed solution (a "
                             "goal dividing by a state, or taking its logarithm, where U is 0 "
                             "or below): solve with an absolute_tolerance below that state's "
                             "size (for goal=, the starting one)")
        return values


def _time_structure(expr, ode):
    """(breakpoints, features) of the integrand ``expr`` in t on [t0, T], found as for a
    right-hand side: of an ODE whose one equation is the integrand (the states it reads
    held as states, so that only its terms free of them are searched)."""
    from dolfinode.events import breakpoints, switched  # (events imports the solver)
    from dolfinode.ode import ODE

    read = sorted(expr.free_symbols & set(ode.states), key=ode.index)
    probe = ODE({sp.Dummy("goal"): expr, **dict.fromkeys(read, sp.S.Zero)},
                u0=np.zeros(1 + len(read)), T=ode.T, t0=ode.t0)
    _, switches = switched(probe)
    features = narrow_features(probe)
    return breakpoints(probe, switches, (), features.edges()), features


def _weights(spec, ode, what):
    if isinstance(spec, Mapping):
        psi = np.zeros(ode.N)
        for key, value in spec.items():
            try:
                i = ode.index(key)  # a state symbol or its name
            except ValueError:
                listed = ", ".join(s.name for s in ode.states[:10])
                raise ValueError(f"the {what} goal names {key!r}, which is not a state; states "
                                 f"are {listed}{', ...' if ode.N > 10 else ''}") from None
            psi[i] = _number(value, what)
    elif isinstance(spec, (Sequence, np.ndarray)) and not isinstance(spec, str):
        if np.ndim(spec) != 1 or len(spec) != ode.N:
            raise ValueError(f"the {what} goal vector must have {ode.N} entries (one per state), "
                             f"got shape {np.shape(spec)}")
        psi = np.array([_number(v, what) for v in spec])
    else:
        raise TypeError(f"the {what} goal must be a dict by state, a sequence of {ode.N} "
                        f"numbers or a sympy expression of the states, got {spec!r}")
    if not np.any(psi):
        raise ValueError(f"the {what} goal weighs every state by zero")
    return psi


def _number(value, what):
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"the {what} goal weights must be numbers, got {value!r}") from None
    if not np.isfinite(value):
        raise ValueError(f"the {what} goal weights must be finite, got {value}")
    return value


def resolve(goal, ode):
    """(final, integral): the parts of ``goal`` as :class:`_Functional` (or None)."""
    goal = Goal.parse(goal)
    final = None if goal.final is None else _Functional(goal.final, ode, "final", False)
    integral = (None if goal.integral is None
                else _Functional(goal.integral, ode, "integral", True))
    return final, integral
