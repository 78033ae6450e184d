"""Goal-oriented adaptivity: primal -> dual -> per-component tolerances -> primal.

The residual-based step control of :mod:`dolfinode.adaptivity` keeps every component's
indicator k^p |R_i| below its absolute tolerance atol_i, which makes its share b_i of the
error bound (see :mod:`dolfinode.dual.estimate`) proportional to atol_i. After each primal
solve the shares are equidistributed towards a target below the tolerance:

    atol_i <- atol_i * clamp(theta * TOL * gamma / (N b_i), 1/F, F),
    gamma = sum_i b_i / |value|,

where gamma >= 1 accounts for the cancellation between the local contributions, theta = 0.5
is the safety margin and F = 100 limits the change per iteration. The shares do not see the
error of the discrete (nonlinear) solves, which is relative to each atol_i: a component whose
tolerance was raised is solved less exactly, and the goal reads that error as the estimate's
orthogonality defect d. Where d exceeds theta TOL / 2 the discrete tolerance factor is
divided by F (an iteration's error falls in steps, one more iteration per slab at a time).
The defect also holds the error of the primal's quadrature of f(U), which the steps set
and the discrete tolerance does not: where d fell by less than ``_FALL`` after a division,
the division stops and each component's share of d joins its share b_i (u' = u^2 to
T = 0.95, cG(2), goal u(T): d = 0.6 x TOL stayed as the factor fell from 1e-5 to 1e-13,
the shares sat at their target, and the loop ended above TOL or Newton failed at the
unreachable discrete tolerance). The loop stops when the
estimate is below TOL and no tolerance would grow by more than ``_BALANCED`` (the error is
balanced between the components), and returns the cheapest solution (fewest elements) whose
estimate met TOL. A component whose residual
does not reach the goal (b_i = 0) has its tolerance raised by F each iteration, up to
``_LOOSEST`` times its size, and takes correspondingly large steps with mcG(q)/mdG(q).
"""
import warnings

import numpy as np

from dolfinode.dual.estimate import estimate_linearised
from dolfinode.errors import SolverError
from dolfinode.parameters import DEFAULTS
from dolfinode.solve import MIN_TOLERANCE

#: Fraction of the tolerance the next iteration aims at.
_THETA = 0.5
#: Largest change of a component's tolerance per iteration.
_FACTOR = 100.0
#: Largest absolute tolerance relative to max(1, max |U_i|).
_LOOSEST = 1e-2
#: Once the tolerance is met, iterate on only while some tolerance would grow more than this.
_BALANCED = 10.0
#: A defect that fell by less than this factor after the discrete tolerance was divided by
#: _FACTOR is the primal's quadrature error (set by the steps), not the discrete solves'.
_FALL = 2.0
#: Primal/dual iterations before giving up.
MAXIMUM_ITERATIONS = 8


def solve_for_goal(solve, ode, method, goal, tolerance, parameters):
    """Iterate primal and dual solves until |M(U) - M(u)| is estimated below ``tolerance``.

    Parameters
    ----------
    solve : the primal driver :func:`dolfinode.solve` (called without a goal)
    ode, method : as for :func:`dolfinode.solve`
    goal : any goal form of :class:`dolfinode.Goal`
    tolerance : float
        Requested bound on the estimated error in the goal.
    parameters : dict
        Further primal parameters; ``absolute_tolerance`` is the starting tolerance per state
        (default ``tolerance``).

    Returns
    -------
    Solution
        The cheapest primal solution that met the tolerance (else the last one), with ``sol.error_estimate`` (an
        :class:`~dolfinode.dual.ErrorEstimate`) and ``sol.stats["goal iterations"]``,
        ``sol.stats["goal history"]`` (estimate, bound and elements per iteration) and
        ``sol.stats["goal tolerance reached"]``. A :class:`RuntimeWarning` says when the
        tolerance was not reached: within ``MAXIMUM_ITERATIONS``, or before the tolerances
        it needs fall below what double precision resolves (:func:`unresolvable`), or a
        primal solve at tightened tolerances fails (its error in the warning).
    """
    parameters = dict(parameters)
    start = parameters.pop("absolute_tolerance", None)
    atol = np.full(ode.N, tolerance) if start is None else np.broadcast_to(
        np.asarray(start, dtype=float), (ode.N,)).copy()
    discrete = parameters.pop("discrete_tolerance_factor",
                              DEFAULTS["discrete_tolerance_factor"])
    history = []
    best = None
    tightened = None  # the defect when the discrete tolerance was last divided
    step_bound = False  # the defect is the quadrature's: the steps must shrink
    why = f"after {MAXIMUM_ITERATIONS} iterations"
    for iteration in range(1, MAXIMUM_ITERATIONS + 1):
        # rtol far below every atol: the dual weights alone set each component's tolerance
        # (not below what double precision resolves: :func:`unresolvable` stops before)
        try:
            sol = solve(ode, method, tolerance=max(1e-3 * atol.min(), MIN_TOLERANCE),
                        absolute_tolerance=atol, discrete_tolerance_factor=discrete,
                        **parameters)
        except SolverError as error:
            if iteration == 1:
                raise
            why = (f"because the primal solve at the absolute tolerances the loop chose for "
                   f"it (down to {atol.min():.3g}) failed: {error}")
            break
        est = estimate_linearised(sol, goal)
        sol.error_estimate = est
        history.append({"value": est.value, "bound": est.bound,
                        "elements": int(sol.stats["elements"]),
                        "absolute_tolerance": atol.copy()})
        met = abs(est.value) <= tolerance
        if met and (best is None or sol.stats["elements"] < best.stats["elements"]):
            best = sol
        large = est.orthogonality_defect > _THETA * tolerance / 2
        if large and tightened is not None and est.orthogonality_defect > tightened / _FALL:
            step_bound = True
        size = np.abs(sol.y).max(axis=1)
        new = _update_tolerances(atol, est, tolerance, size, step_bound)
        if met and np.all(new <= _BALANCED * atol):
            break
        below = unresolvable(ode, new, size)
        if below is not None:
            if not met:
                why = below
            break
        atol = new
        tightened = None
        if large and not step_bound:
            discrete /= _FACTOR
            tightened = est.orthogonality_defect
    reached = best is not None
    if not reached:
        best = sol
        warnings.warn(f"goal-oriented adaptivity stopped {why}, with the estimated goal error "
                      f"{abs(best.error_estimate.value):.3g} above the tolerance "
                      f"{tolerance:.3g}; use a higher-order method or a looser tolerance",
                      RuntimeWarning, stacklevel=3)
    best.stats.update({"goal iterations": iteration, "goal history": history,
                       "goal tolerance reached": reached})
    return best


def unresolvable(ode, atol, size):
    """Why the absolute tolerances ``atol`` the loop chose cannot be solved for, or None:
    one is below what double precision resolves at its component's size (MIN_TOLERANCE x
    max(|u0_i|, max |U_i| = ``size``_i)), where the step control's indicator is rounding.
    A goal as sensitive as 1/u(T) to a u that decays from 1 to 3e-7 (u' = -3u, T = 5, goal
    tolerance 1e-2) asked atol = 1e-14 with a loop-chosen tolerance of 1e-17, and the solve
    raised an error about that tolerance, which the user had not given."""
    floor = MIN_TOLERANCE * np.maximum(np.abs(ode.u0), size)
    if np.all(atol >= floor):
        return None
    i = int(np.argmax(floor / atol))
    return (f"because the goal needs an absolute tolerance of {atol[i]:.3g} on "
            f"{ode.states[i].name} (its dual weight: the goal is that sensitive to it), below "
            f"what double precision resolves at its size {floor[i] / MIN_TOLERANCE:.3g} "
            f"({floor[i]:.3g}); a goal of a component that becomes small (1/u, log u) is "
            f"better posed as its relative error, or give a goal tolerance the estimate can "
            f"reach")


def _update_tolerances(atol, est, tolerance, size, step_bound=False):
    shares = est.bound_contributions
    if step_bound:
        shares = shares + np.abs(est.defect_contributions)
    total = shares.sum()
    gamma = max(total / max(abs(est.value), 1e-300), 1.0)
    target = _THETA * tolerance * gamma / len(atol)
    with np.errstate(divide="ignore"):
        factor = np.where(shares > 0, target / shares, _FACTOR)
    atol = atol * np.clip(factor, 1.0 / _FACTOR, _FACTOR)
    return np.minimum(atol, _LOOSEST * np.maximum(size, 1.0))
