"""Numba signatures of the generated kernels: fixed, so that the time-stepping loops that
call them through first-class function types compile once and are cached."""
from numba import types

_vec = types.float64[::1]

#: f(u, t, p, out): the full right-hand side, written into out.
RHS = types.void(_vec, types.float64, _vec, _vec)
#: f_i(i, u, t, p): one component of the right-hand side.
COMPONENT = types.float64(types.int64, _vec, types.float64, _vec)
#: J(u, t, p, data): the Jacobian df/du, its nonzero values in CSR order written into data.
JACOBIAN = types.void(_vec, types.float64, _vec, _vec)

RHS_TYPE = types.FunctionType(RHS)
COMPONENT_TYPE = types.FunctionType(COMPONENT)
JACOBIAN_TYPE = types.FunctionType(JACOBIAN)
