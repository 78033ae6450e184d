"""Relaxing fast components on their slow manifold: the quasi-steady-state approximation.

A fast component whose own rate is a large real negative number (eps c' = s - (s + K) c of
Michaelis-Menten) does not oscillate about an average but relaxes to the slow manifold
f_S(u_A, u_S, t) = 0 (S the relaxing components, A the active ones), which moves with the
slow state. Frozen at a window's average it is wrong as soon as the slow state moves (a
staircase at every rebuild). In the reduced model it follows the manifold: started on it by
Newton's method with the Jacobian (:func:`project`), it moves along it by the derivative of
the constraint,

    d/dt f_S = 0:   u_S' = -(df_S/du_S)^{-1} (df_S/du_A u_A' + df_S/dt),

a non-stiff equation (:func:`manifold_rates`, from sympy). Each reduced solve starts from a
projection, so the drift off the manifold is that of one segment's discretisation.
"""
import numpy as np
import sympy as sp

from dolfinode.errors import SolverError
from dolfinode.ode import t

#: Newton iterations onto the manifold, and their relative tolerance.
NEWTON_ITERATIONS = 30
NEWTON_TOLERANCE = 1e-13


def manifold_rates(states, constraint, reduced, slaved):
    """The right-hand sides -(dF/du_S)^{-1} (dF/du_O r_O + dF/dt) of the slaved components S
    (boolean mask): F = ``constraint`` (the full model's f_S), r_O = ``reduced`` on the other
    components O (zero for frozen ones). Returns one expression per slaved component."""
    S = [i for i, s in enumerate(slaved) if s]
    others = [i for i, s in enumerate(slaved) if not s]
    F = sp.Matrix(constraint)
    F_S = F.jacobian([states[i] for i in S])
    moving = F.jacobian([states[i] for i in others]) * sp.Matrix([reduced[i] for i in others])
    rates = -F_S.LUsolve(moving + F.diff(t))
    return [sp.cancel(r) if len(S) == 1 else r for r in rates]


def project(compiled, u, time, slaved):
    """u with its slaved components solved from f_S(u, time) = 0 by Newton's method, started
    from their values in u."""
    S = np.flatnonzero(slaved)
    if not S.size:
        return u
    u = np.array(u, dtype=float)
    for _ in range(NEWTON_ITERATIONS):
        F = compiled.f(u, time)[S]
        J = compiled.jacobian_matrix(u, time).tocsr()[S][:, S].toarray()
        step = np.linalg.solve(J, F)
        u[S] -= step
        if np.max(np.abs(step)) <= NEWTON_TOLERANCE * (1 + np.max(np.abs(u[S]))):
            return u
    raise SolverError(f"automatic modeling: Newton's method for the slow manifold of the "
                      f"relaxing components did not converge at t = {time:.6g} (last step "
                      f"{np.max(np.abs(step)):.3g}); the manifold may fold there: solve with "
                      "subgrid_model='constant' or without automatic_modeling", t=time)
