"""The start and the mono-adaptive loop of a prepared solve (:class:`dolfinode.Solver`) in one
compiled call over a work space made once per interval.

Called from Python, a compiled function unboxes each argument (about 40 ns an array, more
in a tuple): the ~40 arrays of :func:`~dolfinode.timeslab.start.start` and
:func:`~dolfinode.timeslab.mono.advance` were half the compiled time of a small solve. The
work space is a numba structref holding both argument tuples and both compiled functions (as
first-class functions: called through their addresses, so this module's cached code holds
no copy of theirs), and the initial values the state starts from (written by a call whose
u0 is new); a call unboxes that one object.
"""
from numba import types
from numba.experimental import structref

from dolfinode.compile.jit import Loop
from dolfinode.timeslab import mono
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
_VECTOR = types.float64[::1]
WORKSPACE_TYPE = _WorkspaceType([("start", _START), ("start_arguments", _START_ARGUMENTS),
                                 ("loop", _LOOP), ("loop_arguments", _LOOP_ARGUMENTS),
                                 ("x", _VECTOR), ("u0", _VECTOR)])


def _workspace(start, start_arguments, loop, loop_arguments, x, u0):
    """The work space of :func:`run` (``start``, ``loop``: the compiled dispatchers; ``x``
    the state vector among their arguments, ``u0`` the initial values it starts from)."""
    w = structref.new(WORKSPACE_TYPE)
    w.start, w.start_arguments = start, start_arguments
    w.loop, w.loop_arguments = loop, loop_arguments
    w.x, w.u0 = x, u0
    return w


def _run(w):
    """x = u0, start(*start_arguments), then, if it returned READY, loop(*loop_arguments);
    returns the loop's status (>= 0), or minus the start's where it is not READY."""
    x, u0 = w.x, w.u0
    for i in range(x.size):  # (a slice assignment took 2.8 s more CPU to compile)
        x[i] = u0[i]
    started = w.start(*w.start_arguments)
    if started != READY:
        return -started
    return w.loop(*w.loop_arguments)


#: Workspace(start dispatcher, start's arguments, loop dispatcher, loop's arguments, x, u0),
#: type checked (called through the dispatcher: once per interval of a Solver).
workspace = Loop(_workspace, WORKSPACE_TYPE(_START, _START_ARGUMENTS, _LOOP, _LOOP_ARGUMENTS,
                                            _VECTOR, _VECTOR),
                 "the prepared call's work space", 1)
run = Loop(_run, types.int64(WORKSPACE_TYPE), "the prepared call", 1)
