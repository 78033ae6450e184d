"""Signatures of the generated C kernels, as numba first-class function types.

The time-stepping loops take the kernels as arguments of these fixed types, so they compile
once (and are cached by numba) whatever the ODE; arrays are passed as data pointers.
"""
import ctypes

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


def _no_refcount():
    try:
        from numba.core.cpu import CPUTargetOptions
    except ImportError:
        return {}
    return {"_nrt": False} if hasattr(CPUTargetOptions, "_nrt") else {}


#: njit options of the slab iterations, which allocate nothing: no reference counting (numba's
#: private ``_nrt`` option; plain njit where a numba version lacks it, slower but the same).
#: numba increfs and decrefs, with atomic instructions, the arrays passed to every helper
#: call: 15-20% of the seed problem's time (N = 4, cG(3): solve 3.9 -> 3.3 ms).
NO_REFCOUNT = _no_refcount()

#: f(u, t, p, out): the full right-hand side, written into out.
RHS = types.void(types.voidptr, types.float64, types.voidptr, types.voidptr)
#: f_i(i, u, t, p, out): one component of the right-hand side, written into out[0].
COMPONENT = types.void(types.int64, types.voidptr, types.float64, types.voidptr, types.voidptr)
#: J(u, t, p, data): the Jacobian df/du, its nonzero values in CSR order written into data.
JACOBIAN = RHS
#: J_i(i, u, t, p, out): row i of df/du, its nonzero values (CSR order) written into out.
JACOBIAN_ROW = COMPONENT

RHS_TYPE = types.FunctionType(RHS)
COMPONENT_TYPE = types.FunctionType(COMPONENT)
JACOBIAN_TYPE = types.FunctionType(JACOBIAN)
JACOBIAN_ROW_TYPE = COMPONENT_TYPE

_p = ctypes.c_void_p
_vector = (None, [_p, ctypes.c_double, _p, _p])
_row = (None, [ctypes.c_long, _p, ctypes.c_double, _p, _p])
CTYPES = {"dn_rhs": _vector, "dn_rhs_component": _row, "dn_jacobian": _vector,
          "dn_jacobian_row": _row}
SIGNATURES = {"dn_rhs": RHS, "dn_rhs_component": COMPONENT, "dn_jacobian": JACOBIAN,
              "dn_jacobian_row": JACOBIAN_ROW}
KERNELS = tuple(CTYPES)


class Kernel(types.WrapperAddressProtocol):
    """A compiled C function, callable from Python (via ctypes) and from numba (by address)."""

    def __init__(self, library, name):
        self._library = library  # keeps the shared library loaded
        self._function = getattr(library, name)
        self._function.restype, self._function.argtypes = CTYPES[name]
        self._signature = SIGNATURES[name]

    def __wrapper_address__(self):
        return ctypes.cast(self._function, ctypes.c_void_p).value

    def signature(self):
        return self._signature

    def __call__(self, *args):
        return self._function(*args)


@intrinsic
def address(typingctx, array, index):
    """The address of ``array[index]`` (a contiguous array's flat index) as a void pointer,
    to pass a kernel part of an array.

    Unlike ``array.ctypes`` (or a slice) it makes no array object, whose atomic reference
    counting numba pays on each call (with the copies it saved in the fixed-point iteration:
    seed problem, N = 4, cG(3), 4.6 -> 3.6 ms per solve).
    """
    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        offset = context.cast(builder, args[1], signature.args[1], types.intp)
        return builder.bitcast(builder.gep(data, [offset]), cgutils.voidptr_t)

    return types.voidptr(array, index), codegen
