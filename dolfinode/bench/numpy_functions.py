"""NumPy right-hand sides and analytic Jacobians for scipy, from the same sympy declaration.

scipy's ``solve_ivp`` gets f(t, y) and J(t, y) lambdified from the expressions dolfinode
compiles (common subexpressions eliminated), so both sides solve exactly the same equations and
scipy's implicit methods get the exact Jacobian, not finite differences. Large systems get a
sparse (CSC) Jacobian, which Radau and BDF factor with a sparse LU.
"""
import numpy as np
import scipy.sparse as sps
import sympy as sp

from dolfinode.ode import t

#: Systems with more components than this get a sparse Jacobian.
SPARSE_FROM = 40


def numpy_functions(ode):
    """f(t, y) and J(t, y) for ``scipy.integrate.solve_ivp`` from an :class:`~dolfinode.ODE`.

    Parameters
    ----------
    ode : ODE

    Returns
    -------
    fun : callable
        fun(t, y) -> ndarray (N,).
    jac : callable
        jac(t, y) -> ndarray (N, N), or a scipy.sparse CSC matrix when N > SPARSE_FROM.
    """
    values = dict(zip(ode.parameter_symbols, ode.parameter_values))
    rhs = [sp.sympify(e).xreplace(values) for e in ode.rhs]
    states = list(ode.states)
    f_args = (t, states)
    f_raw = sp.lambdify(f_args, rhs, modules="numpy", cse=True)

    rows, cols, entries = [], [], []
    for i, expr in enumerate(rhs):
        for j, s in enumerate(states):
            if s in expr.free_symbols:
                d = sp.diff(expr, s)
                if d != 0:
                    rows.append(i)
                    cols.append(j)
                    entries.append(d)
    j_raw = sp.lambdify(f_args, entries, modules="numpy", cse=True) if entries else None
    n = ode.N
    rows, cols = np.array(rows, dtype=np.intp), np.array(cols, dtype=np.intp)

    def fun(s, y):
        return np.array(f_raw(s, y), dtype=float)

    def jac_values(s, y):
        return np.array(j_raw(s, y), dtype=float) if j_raw else np.zeros(0)

    if n > SPARSE_FROM:
        def jac(s, y):
            return sps.csc_matrix((jac_values(s, y), (rows, cols)), shape=(n, n))
    else:
        def jac(s, y):
            J = np.zeros((n, n))
            J[rows, cols] = jac_values(s, y)
            return J
    return fun, jac
