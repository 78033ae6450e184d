"""Signatures of the generated C kernels, as numba first-class function types.

The time-stepping loops take the kernels' addresses (integers) and make them functions of
these fixed types (:func:`rhs_kernel`, :func:`component_kernel`), so they compile once (and are
cached by numba) whatever the ODE; arrays are passed as data pointers. A kernel passed as a
first-class function object instead is typed and its signature unpickled, twice, on every
call of a loop from Python: a large share of a small solve.
"""
import ctypes

from numba import njit, types
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
#: call, a sizeable part of the time of a small system's solve.
NO_REFCOUNT = _no_refcount()

#: f(u, t, p, out): the full right-hand side, written into out; also
#: J(u, t, p, data): the Jacobian df/du, its nonzero values in CSR order written into data.
RHS_TYPE = types.FunctionType(types.void(types.voidptr, types.float64, types.voidptr,
                                         types.voidptr))
#: f_i(i, u, t, p, out): one component of the right-hand side, written into out[0]; also
#: J_i(i, u, t, p, out): row i of df/du, its nonzero values (CSR order) written into out.
COMPONENT_TYPE = types.FunctionType(types.void(types.int64, types.voidptr, types.float64,
                                               types.voidptr, types.voidptr))

_p = ctypes.c_void_p
_vector = (None, [_p, ctypes.c_double, _p, _p])
_row = (None, [ctypes.c_long, _p, ctypes.c_double, _p, _p])
CTYPES = {"dn_rhs": _vector, "dn_rhs_component": _row, "dn_jacobian": _vector,
          "dn_jacobian_row": _row}
KERNELS = tuple(CTYPES)


class Kernel:
    """A compiled C function, callable from Python (via ctypes) and from numba by its
    ``address`` (see :func:`rhs_kernel`)."""

    def __init__(self, library, name):
        self._library = library  # keeps the shared library loaded
        self._function = getattr(library, name)
        self._function.restype, self._function.argtypes = CTYPES[name]
        self.address = ctypes.cast(self._function, ctypes.c_void_p).value

    def __call__(self, *args):
        return self._function(*args)


def _kernel_of(function_type, name):
    """An intrinsic ``name`` making a kernel address (an integer) a function of
    ``function_type``."""

    def kernel(typingctx, kernel_address):
        def codegen(context, builder, signature, args):
            function = cgutils.create_struct_proxy(function_type)(context, builder)
            function.c_addr = builder.inttoptr(args[0], cgutils.voidptr_t)
            # no Python object and no numba-compiled version: called as a C function
            function.py_addr = cgutils.get_null_value(cgutils.voidptr_t)
            function.jit_addr = cgutils.get_null_value(cgutils.voidptr_t)
            return function._getvalue()

        return function_type(kernel_address), codegen

    kernel.__name__ = kernel.__qualname__ = name
    return intrinsic(kernel)


#: rhs_kernel(address): the kernel f(u, t, p, out) or J(u, t, p, data) at that address.
rhs_kernel = _kernel_of(RHS_TYPE, "rhs_kernel")
#: component_kernel(address): the kernel f_i(i, u, t, p, out) or J_i at that address.
component_kernel = _kernel_of(COMPONENT_TYPE, "component_kernel")


@intrinsic
def address(typingctx, array, index):
    """The address of ``array[index]`` (a contiguous array's flat index) as a void pointer,
    to pass a kernel part of an array.

    Unlike ``array.ctypes`` (or a slice) it makes no array object, whose atomic reference
    counting numba pays on each call (and it spares the fixed-point iteration its copies).
    """
    def codegen(context, builder, signature, args):
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        offset = context.cast(builder, args[1], signature.args[1], types.intp)
        return builder.bitcast(builder.gep(data, [offset]), cgutils.voidptr_t)

    return types.voidptr(array, index), codegen


@njit(cache=True)
def call_rhs(kernel_address, u, t, p, out):
    """out = f(u, t) (or the Jacobian's values) through the kernel at ``kernel_address``:
    from Python an order of magnitude cheaper than through ctypes, which makes an object per
    pointer."""
    rhs_kernel(kernel_address)(address(u, 0), t, address(p, 0), address(out, 0))


@njit(cache=True)
def call_rhs_rows(kernel_address, U, t, p, out):
    """out[j] = f(U[j], t[j]) (or the Jacobian's values) for every row j: one compiled call
    for many points (U and out C-contiguous, one row per point)."""
    kernel = rhs_kernel(kernel_address)
    N, width = U.shape[1], out.shape[1]
    for j in range(U.shape[0]):
        kernel(address(U, j * N), t[j], address(p, 0), address(out, j * width))
