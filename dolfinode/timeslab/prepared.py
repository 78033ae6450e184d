"""The start and the mono-adaptive loop of a prepared solve (:class:`dolfinode.Solver`) in one
compiled call over a work space made once per interval.

Called from Python, a compiled function unboxes each argument (about 40 ns an array, more
in a tuple): the ~40 arrays of :func:`~dolfinode.timeslab.start.start` and
:func:`~dolfinode.timeslab.mono.advance` were half the compiled time of a small solve. The
work space is a numba structref holding both argument tuples and both compiled functions (as
first-class functions: called through their addresses, so this module's cached code holds
no copy of theirs), and the initial values the state starts from (written by a call whose
u0 is new); a call unboxes that one object. A run of fewer steps than the error check at T
takes is checked for steps that may span a growing mode (:func:`dolfinode.growth.may_span`)
in the same call: from Python it cost a third of the call.
"""
from numba import types
from numba.experimental import structref

from dolfinode.compile.jit import Loop
from dolfinode.growth import may_span
from dolfinode.timeslab import DONE, SLABS, STORED, mono
from dolfinode.timeslab.start import READY, start


@structref.register
class _WorkspaceType(types.StructRef):
    pass


class Workspace(structref.StructRefProxy):
    """The compiled start and loop with their arguments (made by :data:`workspace`)."""


structref.define_boxing(_WorkspaceType, Workspace)

_START, _LOOP = types.FunctionType(start.signature), types.FunctionType(mono.advance.signature)
_START_ARGUMENTS, _LOOP_ARGUMENTS = (types.Tuple(start.signature.args),
                                     types.Tuple(mono.advance.signature.args))
_VECTOR, _INTEGERS = types.float64[::1], types.int64[::1]
#: (address of J, p, indptr, indices, starts, lengths, nodal values X, counters) of the
#: growth test (:func:`dolfinode.growth.may_span` of the stored steps)
_GROWTH_ARGUMENTS = types.Tuple((types.intp, _VECTOR, _INTEGERS, _INTEGERS, _VECTOR, _VECTOR,
                                 types.float64[:, :, ::1], _INTEGERS))
WORKSPACE_TYPE = _WorkspaceType([("start", _START), ("start_arguments", _START_ARGUMENTS),
                                 ("loop", _LOOP), ("loop_arguments", _LOOP_ARGUMENTS),
                                 ("x", _VECTOR), ("u0", _VECTOR),
                                 ("growth_arguments", _GROWTH_ARGUMENTS),
                                 ("checked_below", types.int64)])
#: :func:`run`'s status of a loop DONE whose steps may span a growing mode (past the loops'
#: return codes, DONE ... CONSTRAINT).
MAY_SPAN = 64


def _workspace(start, start_arguments, loop, loop_arguments, x, u0, growth_arguments,
               checked_below):
    """The work space of :func:`run` (``start``, ``loop``: the compiled dispatchers; ``x``
    the state vector among their arguments, ``u0`` the initial values it starts from; the
    growth test's arguments, and the slabs a run has fewer of to take it)."""
    w = structref.new(WORKSPACE_TYPE)
    w.start, w.start_arguments = start, start_arguments
    w.loop, w.loop_arguments = loop, loop_arguments
    w.x, w.u0 = x, u0
    w.growth_arguments, w.checked_below = growth_arguments, checked_below
    return w


def _run(w):
    """x = u0, start(*start_arguments), then, if it returned READY, loop(*loop_arguments);
    returns the loop's status (>= 0), MAY_SPAN for DONE in fewer than ``checked_below``
    slabs of which a step may span a growing mode, or minus the start's status where it is
    not READY."""
    x, u0 = w.x, w.u0
    for i in range(x.size):  # (a slice assignment took 2.8 s more CPU to compile)
        x[i] = u0[i]
    started = w.start(*w.start_arguments)
    if started != READY:
        return -started
    status = w.loop(*w.loop_arguments)
    jacobian, p, indptr, indices, starts, lengths, X, counters = w.growth_arguments
    if (status == DONE and counters[SLABS] < w.checked_below
            and may_span(jacobian, indptr, indices, p, u0, starts, lengths, X,
                         counters[STORED])):
        return MAY_SPAN
    return status


#: Workspace(start dispatcher, start's arguments, loop dispatcher, loop's arguments, x, u0,
#: growth test's arguments, checked_below), type checked (called through the dispatcher:
#: once per interval of a Solver).
workspace = Loop(_workspace, WORKSPACE_TYPE(_START, _START_ARGUMENTS, _LOOP, _LOOP_ARGUMENTS,
                                            _VECTOR, _VECTOR, _GROWTH_ARGUMENTS, types.int64),
                 "the prepared call's work space", 1)
run = Loop(_run, types.int64(WORKSPACE_TYPE), "the prepared call", 1)
