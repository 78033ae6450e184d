"""dn.solve's kept solvers: a call of :func:`dolfinode.solve` with options seen before on the
same declaration takes the prepared path of a :class:`~dolfinode.Solver` kept for them, so
that the checks and bookkeeping of the options run once (a loop of small solves, a
benchmark's repeats); the solver reads the declaration's values at every call."""
import threading
import weakref

import numpy as np

from dolfinode.family import auto_base
from dolfinode.ode import ODE

#: Option sets of one declaration whose solvers dn.solve keeps; more are forgotten at once.
_KEPT_OPTIONS = 64
_UNSEEN = object()


class _Kept:
    """The solvers :func:`solve_kept` keeps for the declaration ``ode``: by the options of a
    call (None: seen once; False: no prepared path), their shared output buffers and the lock
    that lets one thread at a time use them. A copy of the declaration (a snapshot, a pickle)
    does not take them."""

    def __init__(self, ode=None):
        # (a weak reference: a declaration solved once is freed as before, not by the
        # cycle collector)
        self.ode = weakref.ref(ode) if ode is not None else None
        self.solvers, self.pool, self.lock = {}, {}, threading.Lock()

    def of(self, ode):
        """Whether these are the solvers of ``ode`` (not of the one it was copied from)."""
        return self.ode is not None and self.ode() is ode

    def __reduce__(self):
        return _Kept, ()


def solve_kept(ode, method, tolerance, parameters):
    """:func:`dolfinode.solve` (ode, method, tolerance=tolerance, **parameters) through a
    :class:`~dolfinode.Solver` that ``ode`` keeps for these options (the method, the tolerance
    and the parameters, each with its type), made at their second call; None when the call
    is to take dn.solve's general path: options first seen, not hashable (dicts, lists of
    arrays; a numpy array or a list of numbers is keyed by its values), without a prepared
    path (events, breakpoints, automatic modeling, a progress bar, dense_output other than
    True, ...), or another thread using the solvers. The solver
    reads the declaration's values at every call, so changes of them reach the solve; the
    Solution is bitwise dn.solve's."""
    if not isinstance(ode, ODE):
        return None
    kept = ode.__dict__.get("_kept_solvers")
    if kept is None or not kept.of(ode):
        kept = ode.__dict__["_kept_solvers"] = _Kept(ode)
    key = (method, type(tolerance), tolerance,
           *[(name, type(value), _by_value(value)) for name, value in parameters.items()])
    try:
        solver = kept.solvers.get(key, _UNSEEN)
    except TypeError:  # (option values that do not hash: dicts, lists of arrays)
        return None
    if solver is _UNSEEN:
        if len(kept.solvers) >= _KEPT_OPTIONS:
            kept.solvers.clear()
        kept.solvers[key] = None
        return None
    if solver is False or not kept.lock.acquire(blocking=False):
        return None
    try:
        if solver is None:  # the second call: worth a solver
            solver = kept.solvers[key] = _kept_solver(ode, method, tolerance,
                                                      _copied(parameters), kept.pool)
            if solver is False:
                return None
        sol = solver.solve()
    finally:
        kept.lock.release()
    return sol


def _by_value(value):
    """An option value as a key: a numeric array (an absolute_tolerance per state) by its
    dtype, shape and bytes, a list as a tuple (whose hash fails on unhashable items), others as
    they are."""
    if type(value) is np.ndarray and not value.dtype.hasobject:
        return value.dtype.str, value.shape, value.tobytes()
    return tuple(value) if type(value) is list else value


def _copied(parameters):
    """``parameters`` with arrays and lists copied: the kept solver is found by their values
    at a call, which a later change of the caller's array must not alter."""
    return {name: value.copy() if type(value) in (np.ndarray, list) else value
            for name, value in parameters.items()}


def _kept_solver(ode, method, tolerance, parameters, pool):
    """A :class:`~dolfinode.Solver` for :func:`solve_kept`, its output buffers from ``pool``;
    False when it has no prepared path or dn.solve rejects the options (which says why)."""
    from dolfinode.solver import Solver  # (it imports dolfinode.solve, which imports this)

    if auto_base(method) is not None:
        return False
    solver = object.__new__(Solver)
    try:
        solver._setup(ode, method, {**parameters, "tolerance": tolerance}, pool)
    except (TypeError, ValueError):
        return False
    return solver if solver._buffers is not None else False
