"""Lowering of sympy declarations to compiled numba kernels with exact sparse Jacobians."""
from dolfinode.compile.lowering import CompiledODE, lower

__all__ = ["CompiledODE", "lower"]
